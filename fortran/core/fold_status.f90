!> Status codes shared by every routine that can fail; mirrored in pyfold/errors.py.
module fold_status
   implicit none
   private

   !> Success
   integer, parameter, public :: FOLD_OK = 0
   !> Invalid argument or input file content
   integer, parameter, public :: FOLD_INPUT_ERROR = 1
   !> Iterative solver stopped before its tolerance
   integer, parameter, public :: FOLD_NOT_CONVERGED = 2
   !> File could not be read or written
   integer, parameter, public :: FOLD_IO_ERROR = 3
   !> Particle overlap the collision strategy could not resolve
   integer, parameter, public :: FOLD_OVERLAP = 4
   !> NaN, infinity or another numerical blow-up
   integer, parameter, public :: FOLD_NUMERICAL = 5
end module fold_status
