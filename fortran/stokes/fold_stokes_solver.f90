!> The seam between the particle code and a Stokes backend: settings, code tables
!> and the abstract solver type.
!>
!> A backend solves, on the grid of the cell, for the disturbance flow u~ of a
!> characteristic function chi (viscosity kappa eta_f where chi = 1) under the imposed
!> mean velocity gradient G, and then gives u~, its strain and the viscosity at the
!> voxel centres of this rank's part of the grid, plus the sums and maxima over
!> ranks that rigid_fit (fold_rigid_fit) and bulk_stress (fold_stress) need. Those
!> two and the step of fold_stokes_step take class(stokes_solver_t); what every
!> backend shares above the seam (the checks that begin a solve, the chi -> eta
!> mixing, the convergence verdict) is fold_penalty, and what each can do is its
!> entry in STOKES_BACKENDS below.
!>
!> Setting a backend up needs resources of its own kind (FFTW plans over an MPI slab
!> decomposition for "fft"), so construction is not a binding here: fold_stokes_build
!> makes a solver in one process (the Python extensions, and fold_run on one rank) and
!> fold_stokes_factory over MPI ranks, both from the settings, which they check once.
!>
!> Every integer code below has the same table in Python (pyfold/native/stokes.py);
!> tests/micro/test_code_tables.py checks that the two agree.
module fold_stokes_solver
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_grid, only: grid_t
   implicit none
   private

   !> Backend codes of stokes_settings_t%backend: FFT-preconditioned CG on a periodic
   !> (Lees-Edwards) lattice; hypre on a staggered grid, for cells with walls
   integer(ip), parameter, public :: FOLD_STOKES_FFT = 1, FOLD_STOKES_HYPRE = 2

   !> Derivative discretisation: spectral (i k) or rotated finite differences (Willot 2015)
   integer(ip), parameter, public :: FOLD_DERIV_SPECTRAL = 0, FOLD_DERIV_FD = 1

   !> Viscosity of a partially covered voxel: arithmetic eta_f (1 + (kappa-1) chi),
   !> harmonic 1/eta = (1-chi)/eta_f + chi/(kappa eta_f), geometric eta_f kappa^chi
   integer(ip), parameter, public :: FOLD_MIX_ARITHMETIC = 0, FOLD_MIX_HARMONIC = 1, FOLD_MIX_GEOMETRIC = 2

   !> Initial guess of a warm-started solve: the previous solution x_n (its Fourier
   !> coefficients in lattice coordinates, re-projected on the new lattice), or the
   !> linear extrapolation 2 x_n - x_(n-1) of the last two. (Translating the stored
   !> field along a1 by a fraction of the offset change was tried and only made the
   !> guess worse: measured on a sphere at the cell centre, no shift is the best.)
   integer(ip), parameter, public :: FOLD_GUESS_PREVIOUS = 1, FOLD_GUESS_EXTRAPOLATE = 2

   !> Precision of the FFTs of the FFT backend's CG operator (fold_stokes_fft): double, or
   !> single-precision transforms inside the double-precision CG (tolerance bounded below)
   integer(ip), parameter, public :: FOLD_FFT_DOUBLE = 0, FOLD_FFT_SINGLE = 1

   !> Rigidity of the particles: a viscosity kappa eta_f in the solid (the seed's
   !> penalty, fold_stokes_fft) or the constraint eps(u) = 0 on the solid voxels imposed
   !> by a multiplier (fold_stokes_rigid; FFT backend only, no kappa)
   integer(ip), parameter, public :: FOLD_RIGIDITY_PENALTY = 0, FOLD_RIGIDITY_EXACT = 1

   !> Coverage from which a voxel is rigid under exact rigidity. 1/2: the union of these
   !> voxels approximates the particle without bias, and the partly covered voxels left
   !> (harmonic kappa -> infinity viscosity eta_f / (1 - chi) <= 2 eta_f) keep the solve
   !> well conditioned. (At 1, the penalised solve's kappa -> infinity limit, the nearly full
   !> voxels' unbounded viscosity brings the slow convergence back: 560 against 69 CG
   !> iterations for a sphere of radius 4 voxels at tolerance 1e-8.) [-]
   real(dp), parameter, public :: FOLD_RIGID_COVERAGE = 0.5_dp

   !> Fibre ends of the voxelisation: flat cylinder or capsule (fold_voxelise)
   integer(ip), parameter, public :: FOLD_ENDS_FLAT = 0, FOLD_ENDS_CAPPED = 1

   !> Bounds of the viscosity contrast kappa (pyfold/native/stokes.py KAPPA_MIN, KAPPA_MAX).
   !> kappa = 1 is a particle-free fluid (a test of the solver, no rigidity at all).
   real(dp), parameter, public :: FOLD_KAPPA_MIN = 1.0_dp, FOLD_KAPPA_MAX = 1.0e12_dp

   !> Settings of the fictitious-domain solve. A run reads every field from
   !> /setup/resolved (fold_run_file) and the bindings pass every field
   !> (fortran/bind/stokes_bind.f90), both from the one table of defaults
   !> pyfold/native/stokes.py DEFAULTS; the defaults below serve Fortran-only callers
   !> (fortran/stokes/tests).
   type, public :: stokes_settings_t
      !> Backend (FOLD_STOKES_*)
      integer(ip) :: backend = FOLD_STOKES_FFT
      !> Fluid viscosity eta_f [Pa s]
      real(dp) :: eta_f = 1.0_dp
      !> Viscosity contrast kappa = eta_solid/eta_f in [FOLD_KAPPA_MIN, FOLD_KAPPA_MAX] [-]
      real(dp) :: kappa = 1.0e3_dp
      !> Relative preconditioned residual at which CG stops [-]
      real(dp) :: tol = 1.0e-6_dp
      !> CG iteration cap
      integer(ip) :: max_iter = 3000
      !> FOLD_DERIV_SPECTRAL or FOLD_DERIV_FD
      integer(ip) :: derivative = FOLD_DERIV_FD
      !> Sub-samples per voxel edge for the partial-volume chi (1..8)
      integer(ip) :: subsamples = 3
      !> Fibre ends for voxelisation (FOLD_ENDS_*)
      integer(ip) :: fibre_ends = FOLD_ENDS_FLAT
      !> FFTW planning effort (fold_fft_transport FOLD_PLAN_ESTIMATE / FOLD_PLAN_MEASURE)
      integer :: plan_effort = 0
      !> Mixing rule of the viscosity in partially covered voxels (FOLD_MIX_*)
      integer(ip) :: mixing = FOLD_MIX_HARMONIC
      !> Start CG from the previous solution (re-projected on the new lattice)
      logical :: warm_start = .true.
      !> Initial guess of a warm start (FOLD_GUESS_*)
      integer(ip) :: guess = FOLD_GUESS_PREVIOUS
      !> No-slip walls at y = 0 and y = Ly (the Couette cell of fold_cell): the
      !> disturbance flow vanishes there. A property of the cell, which the caller
      !> copies from it; only a backend that can impose walls accepts it.
      logical :: walls = .false.
      !> Precision of the CG operator's transforms (FOLD_FFT_DOUBLE / FOLD_FFT_SINGLE)
      integer(ip) :: fft_precision = FOLD_FFT_DOUBLE
      !> Rigidity of the particles (FOLD_RIGIDITY_*)
      integer(ip) :: rigidity = FOLD_RIGIDITY_PENALTY
   end type stokes_settings_t

   !> What every Stokes backend holds and does.
   type, abstract, public :: stokes_solver_t
      type(stokes_settings_t) :: set
      !> Grid of the cell (counts, this rank's slab, lattice)
      type(grid_t) :: grid
      !> Dimension and number of strain components (6 in 3-D, 3 in 2-D)
      integer(ip) :: dim = 3, nc = 6
      !> Component pairs (11, 22, 33, 12, 13, 23) or (11, 22, 12)
      integer(ip) :: ci(6) = 0, cj(6) = 0
      !> Iterations and residual of the last solve
      integer(ip) :: iterations = 0
      real(dp) :: residual = 0.0_dp
      !> Residual after each iteration of the last solve (history(0) = initial)
      real(dp), allocatable :: history(:)
      !> Mean strain rate E = sym(G) of the last solve [1/s]
      real(dp) :: E(3, 3) = 0.0_dp
      !> The particles are rigid by a multiplier (FOLD_RIGIDITY_EXACT): their stress is
      !> multiplier_stress, not 2 (eta - eta_f) eps, and their voxels are those with
      !> chi >= FOLD_RIGID_COVERAGE (fold_stress, fold_rigid_fit)
      logical :: exact_rigidity = .false.
      !> Volume mean of the multiplier's stress <chi_s lambda> of the last solve [Pa] and
      !> of its dissipation <chi_s lambda : eps(u)> [Pa/s] (exact rigidity only)
      real(dp) :: multiplier_stress(3, 3) = 0.0_dp
      real(dp) :: multiplier_dissipation = 0.0_dp
   contains
      !> Lattice A (columns a1..a3) of the cell at this time
      procedure(set_lattice_iface), deferred :: set_lattice
      !> Solve for u~ given chi on the local slab and G; FOLD_NOT_CONVERGED keeps the last iterate
      procedure(solve_iface), deferred :: solve
      !> Make u~ at the voxel centres available (velocity_field)
      procedure(compute_iface), deferred :: compute_velocity
      !> Make the strain rate of u~ at the voxel centres available (strain_field)
      procedure(compute_iface), deferred :: compute_strain
      !> Component c of u~ (after compute_velocity) [m/s]; indices (1:nx, local slab)
      procedure(field_iface), deferred :: velocity_field
      !> Strain component c = (ci(c), cj(c)) of u~ (after compute_strain) [1/s]
      procedure(field_iface), deferred :: strain_field
      !> Viscosity of the last solve [Pa s]
      procedure(viscosity_iface), deferred :: viscosity_field
      !> Sum / maximum of an array over the ranks sharing the grid (in place)
      procedure(reduce_iface), deferred :: sum_all
      procedure(reduce_iface), deferred :: max_all
      !> Release every resource
      procedure(compute_iface), deferred :: destroy
   end type stokes_solver_t

   !> Name and capabilities of one backend: the construction (fold_stokes_build,
   !> fold_stokes_factory), the checks and the messages ask them instead of testing codes.
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

   !> The backends: a new one adds its code above, its module, one entry here and its
   !> construction call (fold_stokes_build or fold_stokes_factory)
   type(stokes_backend_t), parameter, public :: STOKES_BACKENDS(2) = [ &
      stokes_backend_t(FOLD_STOKES_FFT, "fft", fft_transport=.true., serial=.true., walls=.false., &
                       lees_edwards=.true., exact_rigidity=.true., single_precision=.true.), &
      stokes_backend_t(FOLD_STOKES_HYPRE, "hypre", fft_transport=.false., serial=.false., walls=.true., &
                       lees_edwards=.false., exact_rigidity=.false., single_precision=.false.)]

   abstract interface
      subroutine set_lattice_iface(s, A, stat, errmsg)
         import :: stokes_solver_t, dp, msg_len
         class(stokes_solver_t), intent(inout) :: s
         real(dp), intent(in) :: A(3, 3)
         integer, intent(out) :: stat
         character(len=msg_len), intent(out) :: errmsg
      end subroutine set_lattice_iface

      subroutine solve_iface(s, chi, G, stat, errmsg)
         import :: stokes_solver_t, dp, msg_len
         class(stokes_solver_t), intent(inout) :: s
         real(dp), intent(in) :: chi(:, :, :)
         real(dp), intent(in) :: G(3, 3)
         integer, intent(out) :: stat
         character(len=msg_len), intent(out) :: errmsg
      end subroutine solve_iface

      subroutine compute_iface(s)
         import :: stokes_solver_t
         class(stokes_solver_t), intent(inout) :: s
      end subroutine compute_iface

      function field_iface(s, c) result(f)
         import :: stokes_solver_t, dp, ip
         class(stokes_solver_t), intent(in) :: s
         integer(ip), intent(in) :: c
         real(dp), pointer, contiguous :: f(:, :, :)
      end function field_iface

      function viscosity_iface(s) result(f)
         import :: stokes_solver_t, dp
         class(stokes_solver_t), intent(in) :: s
         real(dp), pointer, contiguous :: f(:, :, :)
      end function viscosity_iface

      subroutine reduce_iface(s, x)
         import :: stokes_solver_t, dp
         class(stokes_solver_t), intent(in) :: s
         real(dp), intent(inout) :: x(:)
      end subroutine reduce_iface
   end interface

   public :: stokes_settings_check, stokes_backend, stokes_backend_name

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

   !> Check a settings record; names the offending field and its allowed range.
   subroutine stokes_settings_check(set, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_INPUT_ERROR
      errmsg = ""
      if (set%backend /= FOLD_STOKES_FFT .and. set%backend /= FOLD_STOKES_HYPRE) then
         write (errmsg, '(a,i0)') "stokes settings: backend must be 1 (fft) or 2 (hypre), got ", set%backend
      else if (set%backend == FOLD_STOKES_FFT .and. set%walls) then
         errmsg = "stokes settings: backend 1 (fft) solves fully periodic cells only; a cell with walls needs "// &
                  "backend 2 (hypre)"
      else if (.not. (set%eta_f > 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "stokes settings: eta_f must be > 0, got ", set%eta_f
      else if (.not. (set%kappa >= FOLD_KAPPA_MIN .and. set%kappa <= FOLD_KAPPA_MAX)) then
         write (errmsg, '(a,es10.3)') "stokes settings: kappa must be in [1, 1e12], got ", set%kappa
      else if (.not. (set%tol > 0.0_dp .and. set%tol < 1.0_dp)) then
         write (errmsg, '(a,es10.3)') "stokes settings: tol must be in (0, 1), got ", set%tol
      else if (set%max_iter < 1) then
         write (errmsg, '(a,i0)') "stokes settings: max_iter must be >= 1, got ", set%max_iter
      else if (set%derivative /= FOLD_DERIV_SPECTRAL .and. set%derivative /= FOLD_DERIV_FD) then
         write (errmsg, '(a,i0)') "stokes settings: derivative must be 0 (spectral) or 1 (finite differences), got ", &
            set%derivative
      else if (set%subsamples < 1 .or. set%subsamples > 8) then
         write (errmsg, '(a,i0)') "stokes settings: subsamples must be in 1..8, got ", set%subsamples
      else if (set%mixing < FOLD_MIX_ARITHMETIC .or. set%mixing > FOLD_MIX_GEOMETRIC) then
         write (errmsg, '(a,i0)') "stokes settings: mixing must be 0 (arithmetic), 1 (harmonic) or 2 (geometric), got ", &
            set%mixing
      else if (set%fibre_ends /= FOLD_ENDS_FLAT .and. set%fibre_ends /= FOLD_ENDS_CAPPED) then
         write (errmsg, '(a,i0)') "stokes settings: fibre_ends must be 0 (flat) or 1 (capped), got ", set%fibre_ends
      else if (set%rigidity /= FOLD_RIGIDITY_PENALTY .and. set%rigidity /= FOLD_RIGIDITY_EXACT) then
         write (errmsg, '(a,i0)') "stokes settings: rigidity must be 0 (penalty) or 1 (exact), got ", set%rigidity
      else if (set%rigidity == FOLD_RIGIDITY_EXACT .and. set%backend /= FOLD_STOKES_FFT) then
         errmsg = "stokes settings: rigidity 1 (exact) needs backend 1 (fft); backend 2 (hypre) is penalised only"
      else if (set%guess /= FOLD_GUESS_PREVIOUS .and. set%guess /= FOLD_GUESS_EXTRAPOLATE) then
         write (errmsg, '(a,i0)') "stokes settings: guess must be 1 (previous) or 2 (extrapolate), got ", set%guess
      else
         stat = FOLD_OK
      end if
   end subroutine stokes_settings_check

end module fold_stokes_solver
