!> The construction of a Stokes solver for the executables: a solver of the backend
!> named by its settings (fold_stokes_solver FOLD_STOKES_*, capabilities in
!> stokes_backend) on a grid of n voxels distributed over the ranks of comm.
!>
!> On one rank a backend that runs serially is made by fold_stokes_build's
!> stokes_serial_create, the routine the Python extensions use, so both construct it
!> the same way. Over several ranks: an FFT-transport backend gets FFTW-MPI slabs
!> (fold_fft_mpi; the plans are made here, once) and fold_stokes_build's
!> stokes_transport_solver; hypre gets its staggered grid in slabs along the last axis
!> (fold_stokes_hypre). The settings are checked once, here or in stokes_serial_create.
!> Collective over comm. Needs MPI, so it is linked with the executables
!> (stokes_mpi_sources), not with the Python extensions.
module fold_stokes_factory
   use mpi_f08, only: MPI_Comm, MPI_Comm_size
   use fold_kinds, only: ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_fft_transport, only: fft_transport_t
   use fold_fft_mpi, only: fft_mpi_t, fft_mpi_create, fft_mpi_start
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, stokes_settings_check, FOLD_STOKES_HYPRE, &
                                 stokes_backend_t, stokes_backend, stokes_backend_name
   use fold_stokes_build, only: stokes_serial_create, stokes_transport_solver
   use fold_stokes_hypre, only: stokes_hypre_new
   implicit none
   private

   public :: stokes_solver_create

contains

   !> A solver of backend set%backend on a dim-dimensional grid of n(1:dim) voxels.
   !> On failure solver is not allocated and errmsg names the setting.
   subroutine stokes_solver_create(set, dim, n, comm, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      !> Spatial dimension (2 or 3) and voxel counts (n(3) = 1 in 2-D)
      integer(ip), intent(in) :: dim, n(3)
      !> Ranks sharing the grid
      type(MPI_Comm), intent(in) :: comm
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(stokes_backend_t) :: b
      integer :: nranks

      call MPI_Comm_size(comm, nranks)
      b = stokes_backend(set%backend)
      if (nranks == 1 .and. b%serial) then
         call stokes_serial_create(set, dim, n, solver, stat, errmsg)
         return
      end if
      call stokes_settings_check(set, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (b%fft_transport) then
         call create_slabs(set, dim, n, comm, solver, stat, errmsg)
      else if (set%backend == FOLD_STOKES_HYPRE) then
         call stokes_hypre_new(set, dim, n, comm, solver, stat, errmsg)
      else
         stat = FOLD_INPUT_ERROR
         errmsg = "stokes settings: backend "//stokes_backend_name(set%backend)//" has no construction"
      end if
   end subroutine stokes_solver_create

   !> An FFT-transport solver over FFTW-MPI slabs of comm.
   subroutine create_slabs(set, dim, n, comm, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer(ip), intent(in) :: dim, n(3)
      type(MPI_Comm), intent(in) :: comm
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      class(fft_transport_t), allocatable :: fft
      type(fft_mpi_t), allocatable :: slab

      call fft_mpi_start()
      allocate (slab)
      call fft_mpi_create(slab, comm, dim, n, set%plan_effort, stat, errmsg)
      if (stat == FOLD_OK) call move_alloc(slab, fft)
      call stokes_transport_solver(set, fft, solver, stat, errmsg)
   end subroutine create_slabs

end module fold_stokes_factory
