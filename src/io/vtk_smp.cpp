// Compiled as C++17 (CMakeLists.txt): VTK 9.1's vtkSMPTools.h declares a constructor with a
// template-id (vtkSMPTools_FunctorInternal<Functor, false>(...)), which C++20 rejects.
#include "vtk_smp.hpp"

#include <vtkSMPTools.h>

#include <mutex>

namespace fascicle::io_detail {

void use_sequential_vtk_smp() {
  static std::once_flag once;
  std::call_once(once, [] { vtkSMPTools::SetBackend("Sequential"); });
}

}  // namespace fascicle::io_detail
