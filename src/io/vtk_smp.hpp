// VTK's own parallel loops (vtkSMPTools) for fascicle's VTK I/O.
#pragma once

namespace fascicle::io_detail {

// Makes vtkSMPTools run sequentially (once per process; thread-safe). The VTK XML writer's only
// parallel work is the value range of each array (RangeMin/RangeMax in the file's header), a
// few thousand values per array, while fascicle already writes a frame's files in parallel: the
// TBB backend only added a nested task split and a thread-local set-up per array. Minimum and
// maximum do not depend on the order, so the files are the same.
void use_sequential_vtk_smp();

}  // namespace fascicle::io_detail
