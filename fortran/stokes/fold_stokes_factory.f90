!> The one place that knows every Stokes backend: makes a solver of the backend
!> named by its settings (fold_stokes_solver FOLD_STOKES_*) on a grid of n voxels
!> distributed over the ranks of comm.
!>
!> fft: FFTW-MPI slabs over comm when it has more than one rank, serial FFTW
!> otherwise (fold_fft_mpi, fold_fft_serial); the plans are made here, once.
!> hypre: the staggered-grid solver of fold_stokes_hypre, slabs along the last axis.
!> Collective over comm. Needs MPI, so it is linked with the executables
!> (stokes_mpi_sources), not with the Python extensions, which make their serial
!> FFT solver through fold_stokes_step::stokes_context_init.
module fold_stokes_factory
   use mpi_f08, only: MPI_Comm, MPI_Comm_size
   use fold_kinds, only: ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_fft_backend, only: fft_backend_t
   use fold_fft_serial, only: fft_serial_t, fft_serial_create
   use fold_fft_mpi, only: fft_mpi_t, fft_mpi_create, fft_mpi_start
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, stokes_settings_check, FOLD_STOKES_FFT, &
      FOLD_STOKES_HYPRE
   use fold_stokes_rigid, only: stokes_periodic_new
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

      call stokes_settings_check(set, stat, errmsg)
      if (stat /= FOLD_OK) return
      select case (set%backend)
      case (FOLD_STOKES_FFT)
         call create_fft(set, dim, n, comm, solver, stat, errmsg)
      case (FOLD_STOKES_HYPRE)
         call create_hypre(set, dim, n, comm, solver, stat, errmsg)
      case default
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0)') "stokes settings: backend must be 1 (fft) or 2 (hypre), got ", set%backend
      end select
   end subroutine stokes_solver_create

   subroutine create_fft(set, dim, n, comm, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer(ip), intent(in) :: dim, n(3)
      type(MPI_Comm), intent(in) :: comm
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      class(fft_backend_t), allocatable :: fft
      type(fft_serial_t), allocatable :: serial
      type(fft_mpi_t), allocatable :: slab
      integer :: nranks

      call MPI_Comm_size(comm, nranks)
      if (nranks > 1) then
         call fft_mpi_start()
         allocate (slab)
         call fft_mpi_create(slab, comm, dim, n, set%plan_effort, stat, errmsg)
         if (stat == FOLD_OK) call move_alloc(slab, fft)
      else
         allocate (serial)
         call fft_serial_create(serial, dim, n, set%plan_effort, stat, errmsg)
         if (stat == FOLD_OK) call move_alloc(serial, fft)
      end if
      if (stat /= FOLD_OK) then
         errmsg = "grid: "//trim(errmsg)
         return
      end if
      call stokes_periodic_new(fft, set, solver, stat, errmsg)
   end subroutine create_fft

   !> hypre: staggered grid in slabs along the last axis over comm (fold_stokes_hypre).
   subroutine create_hypre(set, dim, n, comm, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer(ip), intent(in) :: dim, n(3)
      type(MPI_Comm), intent(in) :: comm
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call stokes_hypre_new(set, dim, n, comm, solver, stat, errmsg)
   end subroutine create_hypre

end module fold_stokes_factory
