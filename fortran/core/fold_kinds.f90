!> Numeric kinds used everywhere in the pyfold core (one source of truth).
module fold_kinds
   use, intrinsic :: iso_fortran_env, only: real64, int32, int64
   implicit none
   private

   !> Working precision for all physical quantities [SI units throughout]
   integer, parameter, public :: dp = real64
   !> Default integer kind for counts and indices
   integer, parameter, public :: ip = int32
   !> Wide integer kind for global counters (steps, voxels on large grids)
   integer, parameter, public :: i8 = int64
   !> Length of status messages passed back to callers
   integer, parameter, public :: msg_len = 512
end module fold_kinds
