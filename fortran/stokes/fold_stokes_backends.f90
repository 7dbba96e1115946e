!> What each Stokes backend can do, in one table: its name and capability flags, asked
!> by the construction (fold_stokes_build, fold_stokes_factory) and by messages instead
!> of testing backend codes. A new backend adds its module and one entry here (and
!> its construction call in fold_stokes_build or fold_stokes_factory).
module fold_stokes_backends
   use fold_kinds, only: ip
   use fold_stokes_solver, only: FOLD_STOKES_FFT, FOLD_STOKES_HYPRE
   implicit none
   private

   !> Name and capabilities of one backend.
   type, public :: stokes_backend_t
      !> Code of stokes_settings_t%backend (FOLD_STOKES_*)
      integer(ip) :: code = 0
      !> Name in messages and in the scene ("fft", "hypre")
      character(len=8) :: name = ""
      !> Built on an FFT transport (fold_fft_transport), serial or FFTW-MPI
      logical :: fft_transport = .false.
      !> Runs in one process without MPI (the Python extensions)
      logical :: serial = .false.
      !> No-slip walls (a Couette cell)
      logical :: walls = .false.
      !> A sheared (Lees-Edwards) or deforming lattice
      logical :: lees_edwards = .false.
      !> Exact rigidity (FOLD_RIGIDITY_EXACT) besides the penalty
      logical :: exact_rigidity = .false.
      !> Single-precision transforms (FOLD_FFT_SINGLE)
      logical :: single_precision = .false.
   end type stokes_backend_t

   !> The backends, indexed by their code
   type(stokes_backend_t), parameter, public :: STOKES_BACKENDS(2) = [ &
      stokes_backend_t(FOLD_STOKES_FFT, "fft", fft_transport=.true., serial=.true., walls=.false., &
                       lees_edwards=.true., exact_rigidity=.true., single_precision=.true.), &
      stokes_backend_t(FOLD_STOKES_HYPRE, "hypre", fft_transport=.false., serial=.false., walls=.true., &
                       lees_edwards=.false., exact_rigidity=.false., single_precision=.false.)]

   public :: stokes_backend, stokes_backend_name

contains

   !> The entry of backend code; an entry with code 0 and no capability for an unknown code.
   pure function stokes_backend(code) result(b)
      integer(ip), intent(in) :: code
      type(stokes_backend_t) :: b
      integer :: k
      do k = 1, size(STOKES_BACKENDS)
         if (STOKES_BACKENDS(k)%code == code) then
            b = STOKES_BACKENDS(k)
            return
         end if
      end do
   end function stokes_backend

   !> Name of backend code ("fft", "hypre"; "?" for an unknown code).
   pure function stokes_backend_name(code) result(name)
      integer(ip), intent(in) :: code
      character(len=:), allocatable :: name
      type(stokes_backend_t) :: b
      b = stokes_backend(code)
      if (b%code == 0) then
         name = "?"
      else
         name = trim(b%name)
      end if
   end function stokes_backend_name

end module fold_stokes_backends
