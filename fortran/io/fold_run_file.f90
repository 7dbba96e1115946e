!> Reader of a pyfold run file: `/setup/resolved` (parameters) and `/initial`
!> (the particle population), with range checks that name the dataset.
!>
!> The file is written by the Python scene layer (`pyfold run`, h5py); see the
!> micro contract. h5py stores C-ordered arrays, so `/initial/x` of Python shape
!> (n, dim) is read here as the Fortran `x(dim, n)`, and the velocity gradient
!> stored with `G[i, j] == G_ij` comes in transposed and is transposed back.
!> The Stokes settings (`stokes_grid`, `stokes_backend`, `stokes_tolerance`,
!> `stokes_max_iterations`, `stokes_kappa`, `stokes_derivative`, `stokes_fft_plan`,
!> `stokes_mixing`, `stokes_subsamples`, `stokes_fibre_ends`, `stokes_warm_start`,
!> `time_scheme`; optional `stokes_initial_guess`, `stokes_solve_every`, `stokes_fft_precision`,
!> `stokes_fibre_radius_scale`, `stokes_reuse`, `stokes_fibre_shells`) are read
!> only when `hydrodynamics` = 1, so Jeffery run files need not carry them; every
!> setting that changes results is read, none is left at a default of the solver.
!> Any problem is returned as FOLD_INPUT_ERROR (wrong content) or FOLD_IO_ERROR
!> (missing dataset, unreadable file) with the dataset path and the allowed range.
!> The ranges, codes and optional-key defaults of the scene settings are the registry's
!> (pyfold/scene/registry.py, generated into fortran/core/fold_settings.f90), so what
!> `pyfold validate` accepts is read here; which backend a cell needs is the registry's
!> capability table (FOLD_BACKEND_WALLS, FOLD_BACKEND_LEES_EDWARDS).
module fold_run_file
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_IO_ERROR
   use fold_particles, only: particle_set_t, particles_init, particles_check
   use fold_stokes_solver, only: stokes_settings_t
   use fold_settings, only: FOLD_HYDRO_JEFFERY, FOLD_HYDRO_STOKES, FOLD_BACKEND_NAME, FOLD_BACKEND_WALLS, &
                            FOLD_BACKEND_LEES_EDWARDS, &
                            FOLD_LO_HYDRODYNAMICS, FOLD_HI_HYDRODYNAMICS, FOLD_LO_COLLISIONS, FOLD_HI_COLLISIONS, &
                            FOLD_LO_ALPHA, FOLD_HI_ALPHA, FOLD_LO_CONTACT_MAX_ITER, FOLD_HI_CONTACT_MAX_ITER, &
                            FOLD_LO_ON_CONTACT_CAP, FOLD_HI_ON_CONTACT_CAP, FOLD_LO_LUBRICATION, FOLD_HI_LUBRICATION, &
                            FOLD_LO_TIME_SCHEME, FOLD_HI_TIME_SCHEME, FOLD_LO_STOKES_BACKEND, FOLD_HI_STOKES_BACKEND, &
                            FOLD_LO_STOKES_TOLERANCE, FOLD_HI_STOKES_TOLERANCE, &
                            FOLD_LO_STOKES_MAX_ITERATIONS, FOLD_HI_STOKES_MAX_ITERATIONS, &
                            FOLD_LO_STOKES_KAPPA, FOLD_HI_STOKES_KAPPA, FOLD_LO_STOKES_DERIVATIVE, FOLD_HI_STOKES_DERIVATIVE, &
                            FOLD_LO_STOKES_FIBRE_RADIUS_SCALE, FOLD_HI_STOKES_FIBRE_RADIUS_SCALE, &
                            FOLD_DEF_STOKES_FIBRE_RADIUS_SCALE, &
                            FOLD_LO_STOKES_FFT_PLAN, FOLD_HI_STOKES_FFT_PLAN, FOLD_LO_STOKES_MIXING, FOLD_HI_STOKES_MIXING, &
                            FOLD_LO_STOKES_SUBSAMPLES, FOLD_HI_STOKES_SUBSAMPLES, &
                            FOLD_LO_STOKES_FIBRE_ENDS, FOLD_HI_STOKES_FIBRE_ENDS, &
                            FOLD_LO_STOKES_WARM_START, FOLD_HI_STOKES_WARM_START, &
                            FOLD_LO_STOKES_INITIAL_GUESS, FOLD_HI_STOKES_INITIAL_GUESS, FOLD_DEF_STOKES_INITIAL_GUESS, &
                            FOLD_LO_STOKES_FFT_PRECISION, FOLD_HI_STOKES_FFT_PRECISION, FOLD_DEF_STOKES_FFT_PRECISION, &
                            FOLD_LO_STOKES_RIGIDITY, FOLD_HI_STOKES_RIGIDITY, FOLD_DEF_STOKES_RIGIDITY, &
                            FOLD_LO_STOKES_SOLVE_EVERY, FOLD_HI_STOKES_SOLVE_EVERY, FOLD_DEF_STOKES_SOLVE_EVERY, &
                            FOLD_LO_STOKES_REUSE, FOLD_HI_STOKES_REUSE, FOLD_DEF_STOKES_REUSE, &
                            FOLD_LO_STOKES_FIBRE_SHELLS, FOLD_HI_STOKES_FIBRE_SHELLS, FOLD_DEF_STOKES_FIBRE_SHELLS, &
                            FOLD_LO_SHAPE, FOLD_HI_SHAPE, FOLD_LO_DIM, FOLD_HI_DIM, &
                            FOLD_LO_VISCOSITY, FOLD_HI_VISCOSITY, FOLD_LO_DT, FOLD_HI_DT, FOLD_LO_T_END, FOLD_HI_T_END
   use fold_h5, only: hid_t, hsize_t, h5_open_file, h5_close_file, h5_exists, h5_shape, &
                      h5_read_int, h5_read_real, h5_read_int_array, h5_read_real_array
   implicit none
   private

   !> Hydrodynamics codes of /setup/resolved/hydrodynamics (fold_settings)
   public :: FOLD_HYDRO_JEFFERY, FOLD_HYDRO_STOKES

   !> Everything the run driver needs from /setup/resolved.
   type, public :: run_setup_t
      !> Spatial dimension (2 or 3)
      integer(ip) :: dim = 3
      !> Cell edge lengths (Lx, Ly, Lz) [m]
      real(dp) :: cell_lengths(3) = 0.0_dp
      !> No-slip walls at y = 0 and y = Ly (else fully periodic, Lees-Edwards in shear)
      logical :: walls = .false.
      !> Wall speed U (walls move at -U and +U) [m/s]
      real(dp) :: wall_speed = 0.0_dp
      !> Imposed velocity gradient G(i, j) = du_i/dx_j [1/s]
      real(dp) :: velocity_gradient(3, 3) = 0.0_dp
      !> Shear rate [1/s]
      real(dp) :: shear_rate = 0.0_dp
      !> Fluid viscosity [Pa s]
      real(dp) :: viscosity = 0.0_dp
      !> Time step [s]
      real(dp) :: dt = 0.0_dp
      !> End time [s]
      real(dp) :: t_end = 0.0_dp
      !> Seed of every random draw of the run
      integer(i8) :: seed = 0
      !> FOLD_HYDRO_JEFFERY or FOLD_HYDRO_STOKES
      integer :: hydrodynamics = FOLD_HYDRO_JEFFERY
      !> Contact mode: 0 none, 1 naive, 2 strategy (fold_contacts codes)
      integer :: collisions = 0
      !> Security zone alpha [m]
      real(dp) :: alpha = 0.0_dp
      !> Iteration cap of the contact loop
      integer :: contact_max_iter = 1
      !> On reaching the cap: 0 stop, 1 continue
      integer :: on_contact_cap = 0
      !> Sphere lubrication force on/off
      logical :: lubrication = .false.
      !> Steps between time-series records (>= 1)
      integer(i8) :: output_every = 1
      !> Steps between snapshots (0 = none)
      integer(i8) :: snapshot_every = 0
      !> Steps between checkpoints (0 = none)
      integer(i8) :: checkpoint_every = 0
      !> Number of particle families (entries of /setup/resolved/family_names)
      integer(ip) :: n_families = 1
      !> Number of steps, ceiling(t_end/dt) (the run ends at nsteps*dt >= t_end)
      integer(i8) :: nsteps = 0
      ! ---- Stokes hydrodynamics only (read when hydrodynamics = 1)
      !> Voxel counts of the Stokes grid along a1, a2, a3 (n(3) = 1 in 2-D)
      integer(ip) :: stokes_grid(3) = 1
      !> Settings of the Stokes solver (eta_f = viscosity; every other field from stokes_*)
      type(stokes_settings_t) :: stokes
      !> Time scheme of the Stokes velocities: 1 explicit Euler, 2 Adams-Bashforth 2
      integer(ip) :: time_scheme = 1
      !> A Stokes solve every k-th step, velocities extrapolated in between (optional key, 1 when absent)
      integer(ip) :: stokes_solve_every = 1
      !> Velocities between solves (FOLD_REUSE_*; optional key, linear extrapolation when absent)
      integer(ip) :: stokes_reuse = FOLD_DEF_STOKES_REUSE
   end type run_setup_t

   public :: read_run_file

   character(len=*), parameter :: R = "/setup/resolved/"
   character(len=*), parameter :: INI = "/initial/"

contains

   !> Read and check the run parameters and the initial particle state.
   subroutine read_run_file(path, setup, parts, stat, errmsg)
      !> Run file path
      character(len=*), intent(in) :: path
      type(run_setup_t), intent(out) :: setup
      !> Initial particles (x, p, shape, family, radius, length, xi); v = omega = 0
      type(particle_set_t), intent(out) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: file
      integer :: s2
      character(len=msg_len) :: m2

      call h5_open_file(path, .false., file, stat, errmsg)
      if (stat /= FOLD_OK) return
      call read_setup(file, setup, stat, errmsg)
      if (stat == FOLD_OK) call read_initial(file, setup, parts, stat, errmsg)
      call h5_close_file(file, s2, m2)
      if (stat == FOLD_OK .and. s2 /= FOLD_OK) then
         stat = s2
         errmsg = m2
      end if
   end subroutine read_run_file

   subroutine read_setup(file, s, stat, errmsg)
      integer(hid_t), intent(in) :: file
      type(run_setup_t), intent(inout) :: s
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(i8) :: iv
      real(dp), allocatable :: buf(:)
      integer :: rank
      integer(hsize_t) :: shape(7)
      real(dp), parameter :: big = huge(1.0_dp)

      call get_int(file, R//"dim", FOLD_LO_DIM, FOLD_HI_DIM, iv, stat, errmsg); if (stat /= FOLD_OK) return
      s%dim = int(iv, ip)
      call h5_read_real_array(file, R//"cell_lengths", [3_hsize_t], buf, stat, errmsg); if (stat /= FOLD_OK) return
      s%cell_lengths = buf
      if (.not. all(buf(1:s%dim) > 0.0_dp .and. buf(1:s%dim) <= big)) then
         call range_error(R//"cell_lengths", "the first dim entries must be finite and > 0", stat, errmsg)
         return
      end if
      call get_int(file, R//"walls", 0_i8, 1_i8, iv, stat, errmsg); if (stat /= FOLD_OK) return
      s%walls = iv == 1
      call get_real(file, R//"wall_speed", -big, big, s%wall_speed, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_read_real_array(file, R//"velocity_gradient", [3_hsize_t, 3_hsize_t], buf, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (.not. all(abs(buf) <= big)) then
         call range_error(R//"velocity_gradient", "entries must be finite", stat, errmsg)
         return
      end if
      ! h5py wrote G[i, j] = G_ij row-major; the column-major read gives G_ji.
      s%velocity_gradient = transpose(reshape(buf, [3, 3]))
      call get_real(file, R//"shear_rate", -big, big, s%shear_rate, stat, errmsg); if (stat /= FOLD_OK) return
      call get_real(file, R//"viscosity", FOLD_LO_VISCOSITY, FOLD_HI_VISCOSITY, s%viscosity, stat, errmsg)
      if (stat /= FOLD_OK) return
      call get_real(file, R//"dt", FOLD_LO_DT, FOLD_HI_DT, s%dt, stat, errmsg); if (stat /= FOLD_OK) return
      call get_real(file, R//"t_end", FOLD_LO_T_END, FOLD_HI_T_END, s%t_end, stat, errmsg); if (stat /= FOLD_OK) return
      if (s%t_end/s%dt > 1.0e12_dp) then
         call range_error(R//"t_end", "t_end/dt must be <= 1e12 steps", stat, errmsg)
         return
      end if
      ! The relative slack keeps t_end = k*dt (up to round-off) at exactly k steps.
      s%nsteps = max(1_i8, ceiling(s%t_end/s%dt*(1.0_dp - 1.0e-12_dp), i8))
      call get_int(file, R//"seed", -huge(1_i8), huge(1_i8), s%seed, stat, errmsg); if (stat /= FOLD_OK) return
      call get_int(file, R//"hydrodynamics", FOLD_LO_HYDRODYNAMICS, FOLD_HI_HYDRODYNAMICS, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%hydrodynamics = int(iv)
      call get_int(file, R//"collisions", FOLD_LO_COLLISIONS, FOLD_HI_COLLISIONS, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%collisions = int(iv)
      call get_real(file, R//"alpha", FOLD_LO_ALPHA, FOLD_HI_ALPHA, s%alpha, stat, errmsg); if (stat /= FOLD_OK) return
      call get_int(file, R//"contact_max_iter", FOLD_LO_CONTACT_MAX_ITER, FOLD_HI_CONTACT_MAX_ITER, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%contact_max_iter = int(iv)
      call get_int(file, R//"on_contact_cap", FOLD_LO_ON_CONTACT_CAP, FOLD_HI_ON_CONTACT_CAP, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%on_contact_cap = int(iv)
      call get_int(file, R//"lubrication", FOLD_LO_LUBRICATION, FOLD_HI_LUBRICATION, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%lubrication = iv == 1
      call get_int(file, R//"output_every", 1_i8, huge(1_i8), s%output_every, stat, errmsg); if (stat /= FOLD_OK) return
      call get_int(file, R//"snapshot_every", 0_i8, huge(1_i8), s%snapshot_every, stat, errmsg); if (stat /= FOLD_OK) return
      call get_int(file, R//"checkpoint_every", 0_i8, huge(1_i8), s%checkpoint_every, stat, errmsg)
      if (stat /= FOLD_OK) return
      ! Only the number of families is needed here (names stay in the file for Python).
      call h5_shape(file, R//"family_names", rank, shape, stat, errmsg); if (stat /= FOLD_OK) return
      if (rank /= 1 .or. shape(1) < 1) then
         call range_error(R//"family_names", "must be a 1-D array of at least one name", stat, errmsg)
         return
      end if
      s%n_families = int(shape(1), ip)
      if (s%hydrodynamics == FOLD_HYDRO_STOKES) call read_stokes(file, s, stat, errmsg)
   end subroutine read_setup

   !> The Stokes settings of /setup/resolved (present when hydrodynamics = 1).
   subroutine read_stokes(file, s, stat, errmsg)
      integer(hid_t), intent(in) :: file
      type(run_setup_t), intent(inout) :: s
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(i8) :: iv
      integer(i8), allocatable :: ibuf(:)

      call h5_read_int_array(file, R//"stokes_grid", [3_hsize_t], ibuf, stat, errmsg); if (stat /= FOLD_OK) return
      if (any(ibuf(1:s%dim) < 2 .or. ibuf(1:s%dim) > 4096) .or. (s%dim == 2 .and. ibuf(3) /= 1)) then
         call range_error(R//"stokes_grid", "voxel counts in 2 ... 4096 along each of the dim axes, "// &
                          "the third = 1 in 2-D", stat, errmsg)
         return
      end if
      s%stokes_grid = int(ibuf, ip)
      s%stokes%eta_f = s%viscosity
      call get_int(file, R//"stokes_backend", FOLD_LO_STOKES_BACKEND, FOLD_HI_STOKES_BACKEND, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%backend = int(iv, ip)
      ! Each backend solves one kind of cell (the registry's capability table,
      ! pyfold.scene.registry.backend_for): walls need a backend that imposes them, a
      ! periodic cell in shear one that follows its Lees-Edwards lattice.
      if (s%walls .and. .not. FOLD_BACKEND_WALLS(s%stokes%backend)) then
         call range_error(R//"stokes_backend", "a cell with walls (/setup/resolved/walls = 1) needs a backend that "// &
                          "imposes walls (2 hypre): "//trim(FOLD_BACKEND_NAME(s%stokes%backend))// &
                          " solves fully periodic cells only", stat, errmsg)
         return
      else if (.not. s%walls .and. .not. FOLD_BACKEND_LEES_EDWARDS(s%stokes%backend)) then
         call range_error(R//"stokes_backend", "a periodic cell in shear (/setup/resolved/walls = 0) needs a backend "// &
                          "that follows its Lees-Edwards lattice (1 fft): "//trim(FOLD_BACKEND_NAME(s%stokes%backend))// &
                          " has a rectangular grid, for cells with walls only", stat, errmsg)
         return
      end if
      call get_real(file, R//"stokes_tolerance", FOLD_LO_STOKES_TOLERANCE, FOLD_HI_STOKES_TOLERANCE, s%stokes%tol, &
                    stat, errmsg)
      if (stat /= FOLD_OK) return
      call get_int(file, R//"stokes_max_iterations", FOLD_LO_STOKES_MAX_ITERATIONS, FOLD_HI_STOKES_MAX_ITERATIONS, iv, &
                   stat, errmsg); if (stat /= FOLD_OK) return
      s%stokes%max_iter = int(iv, ip)
      call get_real(file, R//"stokes_kappa", FOLD_LO_STOKES_KAPPA, FOLD_HI_STOKES_KAPPA, s%stokes%kappa, stat, errmsg)
      if (stat /= FOLD_OK) return
      call get_int(file, R//"stokes_derivative", FOLD_LO_STOKES_DERIVATIVE, FOLD_HI_STOKES_DERIVATIVE, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%derivative = int(iv, ip)
      call get_int(file, R//"stokes_fft_plan", FOLD_LO_STOKES_FFT_PLAN, FOLD_HI_STOKES_FFT_PLAN, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%plan_effort = int(iv)
      call get_int(file, R//"stokes_mixing", FOLD_LO_STOKES_MIXING, FOLD_HI_STOKES_MIXING, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%mixing = int(iv, ip)
      call get_int(file, R//"stokes_subsamples", FOLD_LO_STOKES_SUBSAMPLES, FOLD_HI_STOKES_SUBSAMPLES, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%subsamples = int(iv, ip)
      call get_int(file, R//"stokes_fibre_ends", FOLD_LO_STOKES_FIBRE_ENDS, FOLD_HI_STOKES_FIBRE_ENDS, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%fibre_ends = int(iv, ip)
      call get_int(file, R//"stokes_warm_start", FOLD_LO_STOKES_WARM_START, FOLD_HI_STOKES_WARM_START, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%stokes%warm_start = iv == 1
      call get_int(file, R//"time_scheme", FOLD_LO_TIME_SCHEME, FOLD_HI_TIME_SCHEME, iv, stat, errmsg)
      if (stat /= FOLD_OK) return
      s%time_scheme = int(iv, ip)
      ! optional: run files written before the setting existed used the previous solution
      call get_int(file, R//"stokes_initial_guess", FOLD_LO_STOKES_INITIAL_GUESS, FOLD_HI_STOKES_INITIAL_GUESS, iv, &
                   stat, errmsg, if_absent=FOLD_DEF_STOKES_INITIAL_GUESS); if (stat /= FOLD_OK) return
      s%stokes%guess = int(iv, ip)
      ! optional: run files written before the setting existed transformed in double
      call get_int(file, R//"stokes_fft_precision", FOLD_LO_STOKES_FFT_PRECISION, FOLD_HI_STOKES_FFT_PRECISION, iv, &
                   stat, errmsg, if_absent=FOLD_DEF_STOKES_FFT_PRECISION); if (stat /= FOLD_OK) return
      s%stokes%fft_precision = int(iv, ip)
      ! optional: run files written before the setting existed are penalised
      call get_int(file, R//"stokes_rigidity", FOLD_LO_STOKES_RIGIDITY, FOLD_HI_STOKES_RIGIDITY, iv, &
                   stat, errmsg, if_absent=FOLD_DEF_STOKES_RIGIDITY); if (stat /= FOLD_OK) return
      s%stokes%rigidity = int(iv, ip)
      call get_int(file, R//"stokes_solve_every", FOLD_LO_STOKES_SOLVE_EVERY, FOLD_HI_STOKES_SOLVE_EVERY, iv, &
                   stat, errmsg, if_absent=FOLD_DEF_STOKES_SOLVE_EVERY); if (stat /= FOLD_OK) return
      s%stokes_solve_every = int(iv, ip)
      ! optional: run files written before the setting existed extrapolated the solves
      call get_int(file, R//"stokes_reuse", FOLD_LO_STOKES_REUSE, FOLD_HI_STOKES_REUSE, iv, &
                   stat, errmsg, if_absent=FOLD_DEF_STOKES_REUSE); if (stat /= FOLD_OK) return
      s%stokes_reuse = int(iv, ip)
      ! optional: run files written before the setting existed voxelised the geometric radius
      call get_real(file, R//"stokes_fibre_radius_scale", FOLD_LO_STOKES_FIBRE_RADIUS_SCALE, &
                    FOLD_HI_STOKES_FIBRE_RADIUS_SCALE, s%stokes%fibre_radius_scale, stat, errmsg, &
                    if_absent=FOLD_DEF_STOKES_FIBRE_RADIUS_SCALE); if (stat /= FOLD_OK) return
      ! optional: run files written before the setting existed let the added shells overlap
      call get_int(file, R//"stokes_fibre_shells", FOLD_LO_STOKES_FIBRE_SHELLS, FOLD_HI_STOKES_FIBRE_SHELLS, iv, &
                   stat, errmsg, if_absent=FOLD_DEF_STOKES_FIBRE_SHELLS); if (stat /= FOLD_OK) return
      s%stokes%fibre_shells = int(iv, ip)
   end subroutine read_stokes

   subroutine read_initial(file, s, parts, stat, errmsg)
      integer(hid_t), intent(in) :: file
      type(run_setup_t), intent(in) :: s
      type(particle_set_t), intent(out) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: rank, k
      integer(hsize_t) :: shape(7), n, d
      real(dp), allocatable :: buf(:)
      integer(i8), allocatable :: ibuf(:)

      call h5_shape(file, INI//"x", rank, shape, stat, errmsg); if (stat /= FOLD_OK) return
      d = int(s%dim, hsize_t)
      if (rank /= 2 .or. shape(1) /= d .or. shape(2) < 1) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0,a)') INI//"x: expected shape (n >= 1, ", s%dim, ") with dim from /setup/resolved/dim"
         return
      end if
      n = shape(2)
      if (n > huge(1_ip)) then
         call range_error(INI//"x", "more particles than a default integer can count", stat, errmsg)
         return
      end if
      call particles_init(parts, s%dim, int(n, ip), stat, errmsg); if (stat /= FOLD_OK) return

      call h5_read_real_array(file, INI//"x", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      parts%x = reshape(buf, [s%dim, int(n, ip)])
      if (.not. all(abs(buf) <= huge(1.0_dp))) then
         call range_error(INI//"x", "entries must be finite", stat, errmsg)
         return
      end if
      call h5_read_real_array(file, INI//"p", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      parts%p = reshape(buf, [s%dim, int(n, ip)])
      do k = 1, int(n)
         if (.not. abs(norm2(parts%p(:, k)) - 1.0_dp) <= 1.0e-8_dp) then
            stat = FOLD_INPUT_ERROR
            write (errmsg, '(a,i0,a,es12.5,a)') INI//"p: row ", k - 1, " has |p| = ", norm2(parts%p(:, k)), &
               " (allowed: |p| = 1 within 1e-8)"
            return
         end if
      end do
      call h5_read_int_array(file, INI//"shape", [n], ibuf, stat, errmsg); if (stat /= FOLD_OK) return
      if (any(ibuf < FOLD_LO_SHAPE .or. ibuf > FOLD_HI_SHAPE)) then
         call range_error(INI//"shape", "allowed codes 1 (fibre), 2 (sphere), 3 (spheroid)", stat, errmsg)
         return
      end if
      parts%shape = int(ibuf, ip)
      call h5_read_int_array(file, INI//"family", [n], ibuf, stat, errmsg); if (stat /= FOLD_OK) return
      if (any(ibuf < 0 .or. ibuf >= s%n_families)) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0,a)') INI//"family: allowed 0 ... ", s%n_families - 1, &
            " (one per entry of /setup/resolved/family_names)"
         return
      end if
      parts%family = int(ibuf, ip)
      call h5_read_real_array(file, INI//"radius", [n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      if (.not. all(buf > 0.0_dp .and. buf <= huge(1.0_dp))) then
         call range_error(INI//"radius", "must be finite and > 0", stat, errmsg)
         return
      end if
      parts%radius = buf
      call h5_read_real_array(file, INI//"length", [n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      if (.not. all(buf > 0.0_dp .and. buf <= huge(1.0_dp))) then
         call range_error(INI//"length", "must be finite and > 0", stat, errmsg)
         return
      end if
      parts%length = buf
      call h5_read_real_array(file, INI//"xi", [n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      if (.not. all(abs(buf) <= 1.0_dp)) then
         call range_error(INI//"xi", "allowed range [-1, 1]", stat, errmsg)
         return
      end if
      parts%xi = buf
      ! Remaining cross-field rules (sphere length = 2R, prolate spheroids) live with the type.
      call particles_check(parts, stat, errmsg)
      if (stat /= FOLD_OK) errmsg = INI//": "//trim(errmsg)
   end subroutine read_initial

   !> Integer scalar dataset within [lo, hi]; with if_absent, an optional one.
   subroutine get_int(file, name, lo, hi, val, stat, errmsg, if_absent)
      integer(hid_t), intent(in) :: file
      character(len=*), intent(in) :: name
      integer(i8), intent(in) :: lo, hi
      integer(i8), intent(out) :: val
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> The value when the dataset is absent (a setting older run files lack)
      integer(ip), intent(in), optional :: if_absent
      if (present(if_absent)) then
         if (.not. h5_exists(file, name)) then
            val = int(if_absent, i8)
            stat = FOLD_OK
            errmsg = ""
            return
         end if
      end if
      call h5_read_int(file, name, val, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (val < lo .or. val > hi) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,a,i0,a,i0,a,i0,a)') name, " = ", val, " out of range (allowed ", lo, " ... ", hi, ")"
      end if
   end subroutine get_int

   !> Real scalar dataset within [lo, hi] (NaN is always out of range); with if_absent, an
   !> optional one.
   subroutine get_real(file, name, lo, hi, val, stat, errmsg, if_absent)
      integer(hid_t), intent(in) :: file
      character(len=*), intent(in) :: name
      real(dp), intent(in) :: lo, hi
      real(dp), intent(out) :: val
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> The value when the dataset is absent (a setting older run files lack)
      real(dp), intent(in), optional :: if_absent
      if (present(if_absent)) then
         if (.not. h5_exists(file, name)) then
            val = if_absent
            stat = FOLD_OK
            errmsg = ""
            return
         end if
      end if
      call h5_read_real(file, name, val, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (.not. (val >= lo .and. val <= hi)) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,a,es12.5,a,es10.3,a,es10.3,a)') name, " = ", val, " out of range (allowed ", lo, &
            " ... ", hi, ")"
      end if
   end subroutine get_real

   subroutine range_error(name, rule, stat, errmsg)
      character(len=*), intent(in) :: name, rule
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_INPUT_ERROR
      errmsg = name//": out of range ("//rule//")"
   end subroutine range_error

end module fold_run_file
