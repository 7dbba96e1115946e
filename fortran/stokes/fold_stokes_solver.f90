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
!> entry in the settings registry's backend table (stokes_backend below).
!>
!> Setting a backend up needs resources of its own kind (FFTW plans over an MPI slab
!> decomposition for "fft"), so construction is not a binding here: fold_stokes_build
!> makes a solver in one process (the Python extensions, and fold_run on one rank) and
!> fold_stokes_factory over MPI ranks, both from the settings, which they check once.
!>
!> The integer codes, ranges, defaults and backend capabilities come from the settings
!> registry (pyfold/scene/registry.py) through the generated fortran/core/fold_settings.f90;
!> the codes are re-exported here under their usual names.
module fold_stokes_solver
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_grid, only: grid_t
   use fold_settings, only: FOLD_DERIV_SPECTRAL, FOLD_DERIV_FD, &
                            FOLD_MIX_ARITHMETIC, FOLD_MIX_HARMONIC, FOLD_MIX_GEOMETRIC, &
                            FOLD_GUESS_PREVIOUS, FOLD_GUESS_EXTRAPOLATE, FOLD_FFT_DOUBLE, FOLD_FFT_SINGLE, &
                            FOLD_ENDS_FLAT, FOLD_ENDS_CAPPED, FOLD_RIGIDITY_NAME, FOLD_DEF_STOKES_BACKEND, &
                            FOLD_KAPPA_MIN, FOLD_KAPPA_MAX, FOLD_N_BACKENDS, FOLD_BACKEND_NAME, FOLD_BACKEND_WALLS, &
                            FOLD_BACKEND_RIGIDITY, FOLD_BACKEND_FFT_TRANSPORT, FOLD_BACKEND_SERIAL, &
                            FOLD_BACKEND_LEES_EDWARDS, FOLD_BACKEND_SINGLE, &
                            FOLD_LO_STOKES_TOLERANCE, FOLD_HI_STOKES_TOLERANCE, &
                            FOLD_LO_STOKES_MAX_ITERATIONS, FOLD_HI_STOKES_MAX_ITERATIONS, &
                            FOLD_LO_STOKES_SUBSAMPLES, FOLD_HI_STOKES_SUBSAMPLES, &
                            FOLD_LO_STOKES_DERIVATIVE, FOLD_HI_STOKES_DERIVATIVE, &
                            FOLD_LO_STOKES_MIXING, FOLD_HI_STOKES_MIXING, &
                            FOLD_LO_STOKES_FIBRE_ENDS, FOLD_HI_STOKES_FIBRE_ENDS, &
                            FOLD_LO_STOKES_FIBRE_RADIUS_SCALE, FOLD_HI_STOKES_FIBRE_RADIUS_SCALE, &
                            FOLD_DEF_STOKES_FIBRE_RADIUS_SCALE, FOLD_LO_STOKES_FIBRE_SHELLS, FOLD_HI_STOKES_FIBRE_SHELLS, &
                            FOLD_DEF_STOKES_FIBRE_SHELLS, &
                            FOLD_LO_STOKES_RIGIDITY, FOLD_HI_STOKES_RIGIDITY, &
                            FOLD_LO_STOKES_INITIAL_GUESS, FOLD_HI_STOKES_INITIAL_GUESS, &
                            FOLD_DEF_STOKES_KAPPA, FOLD_DEF_STOKES_TOLERANCE, FOLD_DEF_STOKES_MAX_ITERATIONS, &
                            FOLD_DEF_STOKES_DERIVATIVE, FOLD_DEF_STOKES_SUBSAMPLES, FOLD_DEF_STOKES_FIBRE_ENDS, &
                            FOLD_DEF_STOKES_FFT_PLAN, FOLD_DEF_STOKES_MIXING, FOLD_DEF_STOKES_WARM_START, &
                            FOLD_DEF_STOKES_INITIAL_GUESS, FOLD_DEF_STOKES_FFT_PRECISION, FOLD_DEF_STOKES_RIGIDITY
   implicit none
   private

   !> Codes of the settings (fold_settings), under the names the backends use. The codes of
   !> the backends and rigidity formulations themselves (FOLD_STOKES_*, FOLD_RIGIDITY_*) are
   !> named only by the construction that meson generates from the registry
   !> (fold_stokes_build, fold_stokes_factory) and by each one's own module and tests:
   !> nothing else branches on one (tests/micro/test_solver_seam.py).
   public :: FOLD_DERIV_SPECTRAL, FOLD_DERIV_FD, FOLD_MIX_ARITHMETIC, &
             FOLD_MIX_HARMONIC, FOLD_MIX_GEOMETRIC, FOLD_GUESS_PREVIOUS, FOLD_GUESS_EXTRAPOLATE, FOLD_FFT_DOUBLE, &
             FOLD_FFT_SINGLE, FOLD_ENDS_FLAT, FOLD_ENDS_CAPPED, &
             FOLD_KAPPA_MIN, FOLD_KAPPA_MAX

   !> Coverage from which a voxel is rigid under exact rigidity. 1/2: the union of these
   !> voxels approximates the particle without bias, and the partly covered voxels left
   !> (harmonic kappa -> infinity viscosity eta_f / (1 - chi) <= 2 eta_f) keep the solve
   !> well conditioned. (At 1, the penalised solve's kappa -> infinity limit, the nearly full
   !> voxels' unbounded viscosity brings the slow convergence back: 560 against 69 CG
   !> iterations for a sphere of radius 4 voxels at tolerance 1e-8.) [-]
   real(dp), parameter, public :: FOLD_RIGID_COVERAGE = 0.5_dp

   !> Settings of the fictitious-domain solve. A run reads every field from
   !> /setup/resolved (fold_run_file) and the bindings pass every field
   !> (fortran/bind/stokes_bind.f90); the defaults below, the registry's (FOLD_DEF_*),
   !> serve Fortran-only callers (fortran/stokes/tests).
   type, public :: stokes_settings_t
      !> Backend (FOLD_STOKES_*); by default the one of a periodic cell
      integer(ip) :: backend = FOLD_DEF_STOKES_BACKEND
      !> Fluid viscosity eta_f [Pa s]
      real(dp) :: eta_f = 1.0_dp
      !> Viscosity contrast kappa = eta_solid/eta_f in [FOLD_KAPPA_MIN, FOLD_KAPPA_MAX] [-]
      real(dp) :: kappa = FOLD_DEF_STOKES_KAPPA
      !> Relative preconditioned residual at which CG stops [-]
      real(dp) :: tol = FOLD_DEF_STOKES_TOLERANCE
      !> CG iteration cap
      integer(ip) :: max_iter = FOLD_DEF_STOKES_MAX_ITERATIONS
      !> FOLD_DERIV_SPECTRAL or FOLD_DERIV_FD
      integer(ip) :: derivative = FOLD_DEF_STOKES_DERIVATIVE
      !> Sub-samples per voxel edge for the partial-volume chi (1..8)
      integer(ip) :: subsamples = FOLD_DEF_STOKES_SUBSAMPLES
      !> Fibre ends for voxelisation (FOLD_ENDS_*)
      integer(ip) :: fibre_ends = FOLD_DEF_STOKES_FIBRE_ENDS
      !> Radius of the voxelised fibre over its geometric radius: a hydrodynamic radius
      !> calibrated to the grid (the contacts keep the geometric one) [-]
      real(dp) :: fibre_radius_scale = FOLD_DEF_STOKES_FIBRE_RADIUS_SCALE
      !> With fibre_radius_scale > 1, the added shells of near fibres (FOLD_SHELLS_*): they
      !> overlap, or each ends the contacts' security zone short of the other particle
      integer(ip) :: fibre_shells = FOLD_DEF_STOKES_FIBRE_SHELLS
      !> FFTW planning effort (fold_fft_transport FOLD_PLAN_ESTIMATE / FOLD_PLAN_MEASURE)
      integer :: plan_effort = FOLD_DEF_STOKES_FFT_PLAN
      !> Mixing rule of the viscosity in partially covered voxels (FOLD_MIX_*)
      integer(ip) :: mixing = FOLD_DEF_STOKES_MIXING
      !> Start CG from the previous solution (re-projected on the new lattice)
      logical :: warm_start = FOLD_DEF_STOKES_WARM_START
      !> Initial guess of a warm start (FOLD_GUESS_*)
      integer(ip) :: guess = FOLD_DEF_STOKES_INITIAL_GUESS
      !> No-slip walls at y = 0 and y = Ly (the Couette cell of fold_cell): the
      !> disturbance flow vanishes there. A property of the cell, which the caller
      !> copies from it; only a backend that can impose walls accepts it.
      logical :: walls = .false.
      !> Precision of the CG operator's transforms (FOLD_FFT_DOUBLE / FOLD_FFT_SINGLE)
      integer(ip) :: fft_precision = FOLD_DEF_STOKES_FFT_PRECISION
      !> Rigidity of the particles (FOLD_RIGIDITY_*)
      integer(ip) :: rigidity = FOLD_DEF_STOKES_RIGIDITY
   end type stokes_settings_t

   !> A field of a solver on the local slab (a pointer into the backend's storage)
   type, public :: field_ref_t
      real(dp), pointer, contiguous :: r(:, :, :) => null()
   end type field_ref_t

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
      !> The particles are rigid by a multiplier (rigidity exact): their stress is
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
      !> Single-precision transforms (FOLD_FFT_SINGLE)
      logical :: single_precision = .false.
   end type stokes_backend_t

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

   public :: stokes_settings_check, stokes_backend, stokes_backend_name, code_legend

contains

   !> The entry of backend code, from the generated capability table of fold_settings (the
   !> settings registry's BACKENDS); an entry with code 0 and no capability for an unknown code.
   pure function stokes_backend(code) result(b)
      integer(ip), intent(in) :: code
      type(stokes_backend_t) :: b
      if (code < 1 .or. code > FOLD_N_BACKENDS) return
      b = stokes_backend_t(code=code, name=FOLD_BACKEND_NAME(code), fft_transport=FOLD_BACKEND_FFT_TRANSPORT(code), &
                           serial=FOLD_BACKEND_SERIAL(code), walls=FOLD_BACKEND_WALLS(code), &
                           lees_edwards=FOLD_BACKEND_LEES_EDWARDS(code), single_precision=FOLD_BACKEND_SINGLE(code))
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

   !> Check a settings record against the registry's ranges and the backend's capabilities
   !> (fold_settings); names the offending field and its allowed range.
   subroutine stokes_settings_check(set, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_INPUT_ERROR
      errmsg = ""
      if (set%backend < 1 .or. set%backend > FOLD_N_BACKENDS) then
         write (errmsg, '(a,i0,a,i0)') "stokes settings: backend must be 1 ... ", FOLD_N_BACKENDS, &
            " ("//code_legend(FOLD_BACKEND_NAME, 1_ip)//"), got ", set%backend
      else if (set%walls .and. .not. FOLD_BACKEND_WALLS(set%backend)) then
         write (errmsg, '(a,i0,a)') "stokes settings: backend ", set%backend, " ("//trim(FOLD_BACKEND_NAME(set%backend))// &
            ") solves fully periodic cells only; a cell with walls needs a backend that imposes walls ("// &
            code_legend(FOLD_BACKEND_NAME, 1_ip, FOLD_BACKEND_WALLS)//")"
      else if (.not. (set%eta_f > 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "stokes settings: eta_f must be > 0, got ", set%eta_f
      else if (.not. (set%kappa >= FOLD_KAPPA_MIN .and. set%kappa <= FOLD_KAPPA_MAX)) then
         write (errmsg, '(a,es10.3,a,es10.3,a,es10.3)') "stokes settings: kappa must be in [", FOLD_KAPPA_MIN, ", ", &
            FOLD_KAPPA_MAX, "], got ", set%kappa
      else if (.not. (set%tol >= FOLD_LO_STOKES_TOLERANCE .and. set%tol <= FOLD_HI_STOKES_TOLERANCE)) then
         write (errmsg, '(a,es10.3)') "stokes settings: tol must be in (0, 1), got ", set%tol
      else if (set%max_iter < FOLD_LO_STOKES_MAX_ITERATIONS) then
         write (errmsg, '(a,i0,a,i0)') "stokes settings: max_iter must be >= ", FOLD_LO_STOKES_MAX_ITERATIONS, &
            ", got ", set%max_iter
      else if (set%derivative < FOLD_LO_STOKES_DERIVATIVE .or. set%derivative > FOLD_HI_STOKES_DERIVATIVE) then
         write (errmsg, '(a,i0)') "stokes settings: derivative must be 0 (spectral) or 1 (finite differences), got ", &
            set%derivative
      else if (set%subsamples < FOLD_LO_STOKES_SUBSAMPLES .or. set%subsamples > FOLD_HI_STOKES_SUBSAMPLES) then
         write (errmsg, '(a,i0,a,i0,a,i0)') "stokes settings: subsamples must be in ", FOLD_LO_STOKES_SUBSAMPLES, "..", &
            FOLD_HI_STOKES_SUBSAMPLES, ", got ", set%subsamples
      else if (set%mixing < FOLD_LO_STOKES_MIXING .or. set%mixing > FOLD_HI_STOKES_MIXING) then
         write (errmsg, '(a,i0)') "stokes settings: mixing must be 0 (arithmetic), 1 (harmonic) or 2 (geometric), got ", &
            set%mixing
      else if (set%fibre_ends < FOLD_LO_STOKES_FIBRE_ENDS .or. set%fibre_ends > FOLD_HI_STOKES_FIBRE_ENDS) then
         write (errmsg, '(a,i0)') "stokes settings: fibre_ends must be 0 (flat) or 1 (capped), got ", set%fibre_ends
      else if (.not. (set%fibre_radius_scale >= FOLD_LO_STOKES_FIBRE_RADIUS_SCALE .and. &
                      set%fibre_radius_scale <= FOLD_HI_STOKES_FIBRE_RADIUS_SCALE)) then
         write (errmsg, '(a,f4.2,a,f4.2,a,es10.3)') "stokes settings: fibre_radius_scale must be in [", &
            FOLD_LO_STOKES_FIBRE_RADIUS_SCALE, ", ", FOLD_HI_STOKES_FIBRE_RADIUS_SCALE, "], got ", set%fibre_radius_scale
      else if (set%fibre_shells < FOLD_LO_STOKES_FIBRE_SHELLS .or. set%fibre_shells > FOLD_HI_STOKES_FIBRE_SHELLS) then
         write (errmsg, '(a,i0)') "stokes settings: fibre_shells must be 0 (overlap) or 1 (apart), got ", set%fibre_shells
      else if (set%rigidity < FOLD_LO_STOKES_RIGIDITY .or. set%rigidity > FOLD_HI_STOKES_RIGIDITY) then
         write (errmsg, '(a,i0,a,i0,a,i0)') "stokes settings: rigidity must be ", FOLD_LO_STOKES_RIGIDITY, " ... ", &
            FOLD_HI_STOKES_RIGIDITY, " ("//code_legend(FOLD_RIGIDITY_NAME, int(FOLD_LO_STOKES_RIGIDITY, ip))// &
            "), got ", set%rigidity
      else if (.not. FOLD_BACKEND_RIGIDITY(set%rigidity, set%backend)) then
         write (errmsg, '(a,i0,a,i0,a)') "stokes settings: rigidity ", set%rigidity, " ("// &
            trim(FOLD_RIGIDITY_NAME(set%rigidity))//") is not a formulation of backend ", set%backend, &
            " ("//trim(FOLD_BACKEND_NAME(set%backend))//"); the backends that have it: "// &
            code_legend(FOLD_BACKEND_NAME, 1_ip, FOLD_BACKEND_RIGIDITY(set%rigidity, :))
      else if (set%guess < FOLD_LO_STOKES_INITIAL_GUESS .or. set%guess > FOLD_HI_STOKES_INITIAL_GUESS) then
         write (errmsg, '(a,i0)') "stokes settings: guess must be 1 (previous) or 2 (extrapolate), got ", set%guess
      else
         stat = FOLD_OK
      end if
   end subroutine stokes_settings_check

   !> "1 fft, 2 hypre": the code and name of each entry of a generated name table
   !> (fold_settings FOLD_BACKEND_NAME, FOLD_RIGIDITY_NAME; codes from first on), or of
   !> those where mask holds, for messages that list the allowed choices.
   pure function code_legend(names, first, mask) result(text)
      character(len=*), intent(in) :: names(:)
      !> Code of names(1)
      integer(ip), intent(in) :: first
      logical, intent(in), optional :: mask(:)
      character(len=:), allocatable :: text
      character(len=24) :: code
      integer :: i
      text = ""
      do i = 1, size(names)
         if (present(mask)) then
            if (.not. mask(i)) cycle
         end if
         write (code, '(i0)') first + i - 1
         if (len(text) > 0) text = text//", "
         text = text//trim(code)//" "//trim(names(i))
      end do
   end function code_legend

end module fold_stokes_solver
