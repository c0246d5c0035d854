// VTK's own parallel loops (vtkSMPTools) for fascicle's VTK I/O.
#pragma once

namespace fascicle::io_detail {

// Makes vtkSMPTools run sequentially, process-wide (fascicle::use_sequential_vtk_loops in
// polydata.hpp). Returns whether the sequential backend is in use afterwards.
bool use_sequential_vtk_smp();

}  // namespace fascicle::io_detail
