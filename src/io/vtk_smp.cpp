// Compiled as C++17 (CMakeLists.txt): VTK 9.1's vtkSMPTools.h declares a constructor with a
// template-id (vtkSMPTools_FunctorInternal<Functor, false>(...)), which C++20 rejects.
#include "vtk_smp.hpp"

#include <vtkSMPTools.h>

#include <cstdlib>
#include <string>

namespace fascicle::io_detail {

bool use_sequential_vtk_smp() {
  // The user's choice of backend (VTK's own environment variable) is left alone.
  if (std::getenv("VTK_SMP_BACKEND_IN_USE") == nullptr) vtkSMPTools::SetBackend("Sequential");
  return std::string(vtkSMPTools::GetBackend()) == "Sequential";
}

}  // namespace fascicle::io_detail
