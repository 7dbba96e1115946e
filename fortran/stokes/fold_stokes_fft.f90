!> Fictitious-domain Stokes solver on the periodic (skewed) cell: FFT-preconditioned CG.
!>
!> Velocity u = G x + u~, u~ periodic with zero mean; viscosity eta_f in the
!> fluid and kappa eta_f in the solid (Glowinski-Joseph style penalisation,
!> docs/physics.md#fictitious-domain-penalisation). In a partially covered voxel the
!> default is the harmonic (Reuss) mixing 1/eta = (1 - chi)/eta_f + chi/(kappa eta_f);
!> the arithmetic rule eta_f (1 + (kappa - 1) chi)
!> (docs/physics.md#viscosity-of-partially-covered-voxels) is available but makes every
!> touched voxel nearly rigid, i.e. inflates particles by ~h/2: measured for a
!> sphere of radius 4 voxels (kappa 1e3): intrinsic viscosity 3.96 vs 2.35
!> (harmonic; Einstein 2.5) and spin 1.036 vs 1.0036 x gamma_dot/2. With B the symmetric-gradient operator and P the projection
!> on divergence-free fields, u~ solves the symmetric positive definite system
!>     A u~ = P B^H (2 eta B u~) = - P B^H (2 eta E),   E = sym(G),
!> i.e. -div(2 eta eps(u)) + grad p = 0, div u = 0 with p the multiplier of the
!> constraint. Unknowns and CG vectors live in Fourier space; the preconditioner
!> is the inverse of the same operator with a uniform viscosity eta0,
!> M^-1 r = P r / (eta0 |k|^2), exact for a uniform eta (Green operator of
!> Moulinec & Suquet 1998, Comput. Methods Appl. Mech. Eng. 157:69; CG variant of
!> Zeman, Vondrejc, Novak & Marek 2010, J. Comput. Phys. 229:8065). One
!> iteration = B (c2r FFTs), 2 eta (pointwise), B^H (r2c FFTs). The CG iterates
!> are divergence-free (kv . p = 0 on every kept mode), so the strain is traceless
!> and so is the stress 2 eta eps (eta is a scalar field): eps_33 = -eps_11 - eps_22
!> and sigma_33 = -sigma_11 - sigma_22 pointwise. Only the 5 (2-D: 2) independent
!> components are transformed: 10 real 3-D FFTs per iteration in 3-D (4 in 2-D)
!> instead of 12 (6). That is the spectral form (spectral derivatives, and 2-D). In 3-D
!> with the default rotated differences the solver takes the stencil form
!> (stencil_init): 2 eta = 2 eta_f + 2 (eta - eta_f), the uniform part applied in
!> Fourier space (eta_f |kv|^2 p for a divergence-free p) and the rest by the
!> real-space stencil of the scheme over the voxels where eta /= eta_f only
!> (stencil_force, fortran/stokes/fold_cg_kernels.f90.in): 3 c2r of the corner
!> velocity and 3 r2c of the corner force per iteration. The stencil form iterates on
!> the corner grid's own coefficients (unstaggered; converted on entry and exit).
!> Wavevectors of the skewed lattice are k = 2 pi A^-T m. Derivative schemes:
!>  * FOLD_DERIV_SPECTRAL: d = i k; velocity and strain at voxel centres. Every
!>    mode with a Nyquist index is removed from the unknowns (on even grids its
!>    derivative is not Hermitian-consistent and CG stalls,
!>    docs/physics.md#spectral-derivatives-and-even-grids).
!>  * FOLD_DERIV_FD (default): the "rotated" finite-difference scheme of Willot
!>    (2015, C. R. Mecanique 343:232): velocity at voxel corners, strain at voxel
!>    centres from the 2^dim corners (trilinear element, one-point integration):
!>    d_l = n_l (e^{i th_l} - 1) prod_{l' /= l} (1 + e^{i th_l'})/2 in lattice
!>    coordinates = e^{i phi} i rho_l with a common phase, so the discrete Green
!>    operator keeps the closed form with the real vector q = A^-T rho. No
!>    Gibbs ringing at the particle surface; the zero-energy (hourglass) modes
!>    with >= 2 Nyquist indices are removed.
!> Both schemes have d = i phase kv with a real vector kv and a unit phase (1 for the
!> spectral one). The solver works with the staggered variable u' = i phase u^
!> (a unitary, mode-wise change of variable that commutes with P): then
!> B u = sym(kv (x) u'), (B^H sigma)' = kv . sigma, and every per-mode operation is
!> real x complex. The velocity at the voxel centres is u^ avg = -i cosprod u'.
!> Reference viscosity: PCG iterates are invariant under a scalar rescaling of
!> the preconditioner, so eta0 does not change the iteration count (unlike the
!> fixed-point scheme, whose optimum is (eta_min + eta_max)/2). We take the
!> geometric mean sqrt(eta_min eta_max) only so that preconditioned residuals
!> stay O(1) in both phases. Residual: sqrt(<r, M^-1 r> / <b, M^-1 b>)
!> (relative preconditioned, i.e. energy-like, residual).
!> No allocation happens inside the iteration; the FFT plans are made once.
!>
!> Single-precision transforms (settings fft_precision = FOLD_FFT_SINGLE). Spectral
!> form: the 2 ncg transforms of each iteration (and of the warm start's r = b - A x)
!> run on fftwf plans over the first half of the work fields' memory
!> (fft_field_t%rs/cs): the direction pass rounds the strain to single as it writes it,
!> the viscosity pass multiplies by 2 eta/N held in single and sums <p, A p> in double,
!> the update pass widens the stress to double. Stencil form: the velocity goes to
!> real space in double (a difference of rounded corner values would magnify their
!> round-off by up to max|kv| / min|kv|), the force is accumulated and transformed in
!> single: one rounding per contribution and one transform, within the bound below. x, r, p, the preconditioner, every dot product and
!> the residual stay double, and so do the right-hand side, the velocity and strain
!> outputs and stokes_fft_true_residual. CG therefore runs with a perturbed operator
!> A + dA, |dA p| <= eps |A p| in the sense of the stress field, with
!>     eps = (2 log2 N + 4) u_s,   u_s = 2^-24,  N voxels:
!> each of the two transforms adds at most log2 N roundings per value (one per
!> butterfly stage of a radix-2 FFT; Higham 2002, Accuracy and Stability of Numerical
!> Algorithms, sec. 24.1), plus four roundings to single (strain, 2 eta/N, product,
!> stress). With a perturbed product the recursive residual keeps falling, while the
!> true one, b - A x_k, differs from it by the accumulated sum of alpha_i dA p_i
!> (Greenbaum 1997, SIAM J. Matrix Anal. Appl. 18:535; van der Vorst & Ye 2000,
!> SIAM J. Sci. Comput. 22:835), i.e. it stalls at a relative level ~eps. A tolerance
!> >= eps is thus reached by the true residual within a factor 2 (checked by
!> fortran/stokes/tests/test_stokes_single.f90); below it the reported residual would
!> overstate the accuracy, so stokes_fft_init refuses tol < eps (single_tol_min; 2.4e-6
!> at 72^3, 2.7e-6 at 128^3) with a message naming fft_precision. Measured stall of the
!> true residual (sphere of radius 0.2 cell, 32^3, tol 1e-11): 1.5e-7 to 1.9e-7 for
!> kappa = 10, 1e3 and 1e6, against eps = 2.0e-6, no kappa dependence seen. The
!> working tolerances 1e-3..1e-5 are 2..4 orders above the perturbation; the default
!> 1e-6 and the reference 1e-10 of the benchmarks stay double.
module fold_stokes_fft
   use, intrinsic :: iso_c_binding, only: c_float, c_float_complex
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NUMERICAL
   use fold_fft_transport, only: fft_transport_t, fft_field_t, field_free, fields_free, FOLD_PLAN_ESTIMATE
   use fold_grid, only: grid_t, grid_init, grid_set_lattice, grid_total
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, stokes_settings_check, &
                                 FOLD_DERIV_SPECTRAL, FOLD_DERIV_FD, FOLD_MIX_ARITHMETIC, FOLD_MIX_HARMONIC, &
                                 FOLD_MIX_GEOMETRIC, FOLD_GUESS_PREVIOUS, FOLD_GUESS_EXTRAPOLATE, FOLD_FFT_DOUBLE, &
                                 FOLD_FFT_SINGLE
   use fold_penalty, only: solve_begin, penalty_viscosity, solve_verdict
   use fold_cg_kernels_dp, only: direction_strain3, direction_strain2, viscous_energy3, viscous_energy2, &
                                 apply_update3, apply_update2, direction_velocity3, stencil_update3, stencil_force
   use fold_cg_kernels_sp, only: direction_strain3_sp => direction_strain3, direction_strain2_sp => direction_strain2, &
                                 viscous_energy3_sp => viscous_energy3, viscous_energy2_sp => viscous_energy2, &
                                 apply_update3_sp => apply_update3, apply_update2_sp => apply_update2, &
                                 stencil_update3_sp => stencil_update3, stencil_force_sp => stencil_force
   implicit none
   private

   ! the settings and codes of the seam, re-exported for callers of this backend
   public :: stokes_settings_t, stokes_settings_check, FOLD_DERIV_SPECTRAL, FOLD_DERIV_FD, FOLD_MIX_ARITHMETIC, &
             FOLD_MIX_HARMONIC, FOLD_MIX_GEOMETRIC, FOLD_GUESS_PREVIOUS, FOLD_GUESS_EXTRAPOLATE, FOLD_FFT_DOUBLE, &
             FOLD_FFT_SINGLE

   !> Largest fraction of the cell's voxels with eta /= eta_f for which a solve takes the
   !> stencil form: its pass costs in proportion to those voxels, the spectral form's
   !> 4 extra transforms do not (the two forms give the same operator to round-off, so
   !> this chooses the speed only). Crossover measured with
   !> benchmarks/bench_stokes_fft.py --forms (docs/physics.md#fft-stokes-solver).
   real(dp), parameter, public :: STENCIL_FRACTION_MAX = 0.2_dp

   !> Solver state: plans, grid, work fields and the Fourier-space solution.
   type, extends(stokes_solver_t), public :: stokes_fft_t
      class(fft_transport_t), allocatable :: fft
      !> Strain components transformed in a CG iteration (traceless: 33 or 22 dropped)
      integer(ip) :: ncg = 5, cg_comp(5) = 0
      !> Strain/stress work fields (nc); after a solve: strain of u~ if requested
      type(fft_field_t), allocatable :: work(:)
      !> Viscosity at voxel centres [Pa s]
      type(fft_field_t) :: eta
      !> 2 eta / N (nxp, nl(2), nl(3)), the stress factor of the unnormalised transforms
      !> in the double-precision operator passes [Pa s]
      real(dp), allocatable :: ceta(:, :, :)
      !> The CG operator in its stencil form (3-D rotated finite differences, every rank
      !> holding >= 1 z-plane): the uniform viscosity's part in Fourier space and the rest
      !> by a real-space stencil over the particles' voxels, 3 + 3 transforms per
      !> iteration instead of 5 + 5 (fortran/stokes/fold_cg_kernels.f90.in, stencil_force)
      logical :: stencil = .false.
      !> The stencil form is available (3-D, rotated differences, >= 1 z-plane per rank);
      !> each solve takes it when the voxels with eta /= eta_f are at most
      !> stencil_fraction_max of the cell (STENCIL_FRACTION_MAX; < 0: never)
      logical :: stencil_ok = .false.
      real(dp) :: stencil_fraction_max = STENCIL_FRACTION_MAX
      !> Stencil form: i phase of every mode, phase = e^{i pi sum_l m_l / n_l}, as
      !> ph1(x index) * ph23(flattened local y, z index) (separable)
      complex(dp), allocatable :: ph1(:), ph23(:)
      !> Stencil form: A^-T(b, l) n_l / 4 of the lattice [1/m]
      real(dp) :: aith(3, 3) = 0.0_dp
      !> Stencil form: the slab's first corner plane and the next rank's (uhi), the force
      !> on the corner plane after the slab (fover) and the previous rank's (frecv), each
      !> (nxp, nl(2), 3); a scratch plane for the unused direction of an exchange
      real(dp), allocatable :: hfirst(:, :, :), uhi(:, :, :), fover(:, :, :), frecv(:, :, :), hscr(:, :, :)
      !> Stencil form: local centres whose viscosity differs from eta_f (i, j, k) and their
      !> 2 (eta - eta_f) / N [Pa s]; nact of the capacity in use
      integer(ip), allocatable :: act(:, :)
      real(dp), allocatable :: dceta(:)
      integer(ip) :: nact = 0
      !> Stencil form: the uniform viscosity's part of <p, A p> from the direction pass
      real(dp) :: e_uniform = 0.0_dp
      !> FOLD_FFT_SINGLE: 2 eta / N in single precision (nxp, nl(2), nl(3)) for the viscosity
      !> pass of the single-precision operator [Pa s]; else size 0
      real(c_float), allocatable :: eta_sp(:, :, :)
      !> The CG operator transforms in single precision (settings fft_precision)
      logical :: single = .false.
      !> Velocity u~ at voxel centres after stokes_fft_velocity (dim fields) [m/s]
      type(fft_field_t), allocatable :: vel(:)
      !> Staggered Fourier coefficients i phase u^ (unnormalised FFT) of u~ and the CG vectors
      !> (nxh, nsl(2), nsl(3), dim; spectral layout of the transport)
      complex(dp), allocatable :: x(:, :, :, :), r(:, :, :, :), p(:, :, :, :), q(:, :, :, :)
      !> Solution of the solve before the last one (FOLD_GUESS_EXTRAPOLATE only; else size 0)
      complex(dp), allocatable :: x_prev(:, :, :, :)
      !> Real derivative vector q of each mode (dim, nxh, nsl(2), nsl(3)), zero on removed modes [1/m]
      real(dp), allocatable :: kv(:, :, :, :)
      !> 1/|q|^2, zero on removed modes (mean, Nyquist/hourglass) [m^2]
      real(dp), allocatable :: ik2(:, :, :)
      !> Modulus of the corner-to-centre average (FD scheme; 1 for the spectral one)
      real(dp), allocatable :: cosprod(:, :, :)
      !> Hermitian weight of each x wavenumber in the half spectrum (1 or 2)
      real(dp), allocatable :: wx(:)
      !> Reference viscosity of the preconditioner [Pa s]
      real(dp) :: eta0 = 1.0_dp
      logical :: have_guess = .false., lattice_set = .false.
      !> x_prev holds the solution before x (a second guess for the extrapolation)
      logical :: have_prev = .false.
   contains
      procedure :: set_lattice => stokes_fft_set_lattice
      procedure :: solve => stokes_fft_solve
      procedure :: compute_velocity => stokes_fft_velocity
      procedure :: compute_strain => stokes_fft_strain
      procedure :: velocity_field => fft_velocity_field
      procedure :: strain_field => fft_strain_field
      procedure :: viscosity_field => fft_viscosity_field
      procedure :: sum_all => fft_sum_all
      procedure :: max_all => fft_max_all
      procedure :: destroy => stokes_fft_destroy
   end type stokes_fft_t

   public :: stokes_fft_init, stokes_fft_new, stokes_fft_set_lattice, stokes_fft_solve, stokes_fft_velocity, &
             stokes_fft_strain, stokes_fft_destroy, stokes_fft_true_residual, stokes_fft_apply, single_tol_min, &
             stokes_fft_apply_cg, stokes_fft_project

   !> Unit round-off of single precision, 2^-24 [-]
   real(dp), parameter, public :: FOLD_SINGLE_ROUNDOFF = 0.5_dp*real(epsilon(1.0_c_float), dp)

   real(dp), parameter :: pi = acos(-1.0_dp)
   complex(dp), parameter :: iu = (0.0_dp, 1.0_dp)

contains

   !> Take over an FFT transport (serial or MPI, plans already made) and allocate
   !> every work array once. The settings are checked by the construction
   !> (fold_stokes_build, fold_stokes_factory); here only what needs the grid.
   subroutine stokes_fft_init(s, fft, set, stat, errmsg)
      type(stokes_fft_t), intent(inout) :: s
      !> Transport; moved into s (deallocated on return)
      class(fft_transport_t), allocatable, intent(inout) :: fft
      type(stokes_settings_t), intent(in) :: set
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: c, nxh, n2, n3

      errmsg = ""
      if (.not. allocated(fft)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "stokes_fft_init: no FFT transport given"
         return
      end if
      stat = FOLD_INPUT_ERROR
      if (set%fft_precision /= FOLD_FFT_DOUBLE .and. set%fft_precision /= FOLD_FFT_SINGLE) then
         write (errmsg, '(a,i0)') "stokes settings: fft_precision must be 0 (double) or 1 (single), got ", &
            set%fft_precision
         return
      end if
      if (set%fft_precision == FOLD_FFT_SINGLE .and. set%tol < single_tol_min(product(int(fft%n, i8)))) then
         write (errmsg, '(a,es9.2,a,i0,a,es9.2,a)') "stokes settings: fft_precision single needs tolerance >= ", &
            single_tol_min(product(int(fft%n, i8))), " on a grid of ", product(int(fft%n, i8)), &
            " voxels (single-precision round-off of the CG operator), got ", set%tol, "; use fft_precision double"
         return
      end if
      stat = FOLD_OK
      call stokes_fft_destroy(s)
      call move_alloc(fft, s%fft)
      s%set = set
      s%dim = s%fft%dim
      call grid_init(s%grid, s%fft%dim, s%fft%n, s%fft%nl, s%fft%off, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (s%dim == 3) then
         s%nc = 6
         s%ci = [1, 2, 3, 1, 1, 2]
         s%cj = [1, 2, 3, 2, 3, 3]
         s%ncg = 5
         s%cg_comp = [1, 2, 4, 5, 6]
      else
         s%nc = 3
         s%ci = [1, 2, 1, 0, 0, 0]
         s%cj = [1, 2, 2, 0, 0, 0]
         s%ncg = 2
         s%cg_comp = [1, 3, 0, 0, 0]
      end if
      allocate (s%work(s%nc), s%vel(s%dim))
      do c = 1, s%nc
         call s%fft%alloc_field(s%work(c))
      end do
      do c = 1, s%dim
         call s%fft%alloc_field(s%vel(c))
      end do
      call s%fft%alloc_field(s%eta)
      allocate (s%ceta(s%fft%nxp, s%fft%nl(2), s%fft%nl(3)))
      s%ceta = 0.0_dp
      call stencil_init(s)
      s%single = set%fft_precision == FOLD_FFT_SINGLE
      if (s%single) then
         call s%fft%plan_single(set%plan_effort, stat, errmsg)
         if (stat /= FOLD_OK) return
         allocate (s%eta_sp(s%fft%nxp, s%fft%nl(2), s%fft%nl(3)))
      else
         allocate (s%eta_sp(0, 0, 0))
      end if
      s%eta_sp = 0.0_c_float
      ! Fourier-space arrays take the transport's spectral layout (fold_fft_transport)
      nxh = s%fft%nxh
      n2 = s%fft%nsl(2)
      n3 = s%fft%nsl(3)
      allocate (s%x(nxh, n2, n3, s%dim), s%r(nxh, n2, n3, s%dim), s%p(nxh, n2, n3, s%dim), s%q(nxh, n2, n3, s%dim))
      allocate (s%kv(s%dim, nxh, n2, n3), s%ik2(nxh, n2, n3), s%cosprod(nxh, n2, n3))
      if (set%guess == FOLD_GUESS_EXTRAPOLATE) then
         allocate (s%x_prev(nxh, n2, n3, s%dim))
      else
         allocate (s%x_prev(0, 0, 0, s%dim))
      end if
      s%x_prev = 0.0_dp
      allocate (s%wx(nxh), s%history(0:set%max_iter))
      s%x = 0.0_dp
      s%r = 0.0_dp
      s%p = 0.0_dp
      s%q = 0.0_dp
      s%wx = 2.0_dp
      s%wx(1) = 1.0_dp
      if (mod(s%grid%n(1), 2) == 0) s%wx(nxh) = 1.0_dp
      s%history = 0.0_dp
      s%have_guess = .false.
      s%have_prev = .false.
      s%lattice_set = .false.
   end subroutine stokes_fft_init

   !> An FFT solver seen through the abstract type: stokes_fft_init on a new object,
   !> which becomes solver on success (on failure solver stays unallocated).
   subroutine stokes_fft_new(fft, set, solver, stat, errmsg)
      !> Transport; moved into the solver (deallocated on return)
      class(fft_transport_t), allocatable, intent(inout) :: fft
      type(stokes_settings_t), intent(in) :: set
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(stokes_fft_t), allocatable :: s
      allocate (s)
      call stokes_fft_init(s, fft, set, stat, errmsg)
      if (stat /= FOLD_OK) then
         call s%destroy()
         return
      end if
      call move_alloc(s, solver)
   end subroutine stokes_fft_new

   !> Set the lattice A (columns a1..a3) and rebuild the per-mode tables.
   subroutine stokes_fft_set_lattice(s, A, stat, errmsg)
      class(stokes_fft_t), intent(inout) :: s
      !> Lattice basis [m]
      real(dp), intent(in) :: A(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: i, j, k, l, l2, m(3), dim, nnyq
      real(dp) :: th, lat(3), ait(3, 3), kk, cosprod
      ! sin and cos of the half angle of every wavenumber index of each axis: the same
      ! values as evaluated per mode, one evaluation per index instead of per mode
      real(dp), allocatable :: sh(:, :), ch(:, :)
      logical :: removed

      call grid_set_lattice(s%grid, A, stat, errmsg)
      if (stat /= FOLD_OK) return
      dim = s%dim
      ait = transpose(s%grid%Ainv)
      allocate (sh(0:maxval(s%grid%n) - 1, 3), ch(0:maxval(s%grid%n) - 1, 3))
      do l = 1, 3
         do i = 0, s%grid%n(l) - 1
            th = 2.0_dp*pi*real(i, dp)/real(s%grid%n(l), dp)
            sh(i, l) = sin(0.5_dp*th)
            ch(i, l) = cos(0.5_dp*th)
         end do
      end do
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            do i = 1, s%fft%nxh
               ! global wavenumber index of the local mode (spectral layout of the transport)
               m(s%fft%saxis) = [i - 1, j - 1, k - 1] + s%fft%soff
               nnyq = count(2*m(1:dim) == s%grid%n(1:dim))
               lat = 0.0_dp
               if (s%set%derivative == FOLD_DERIV_SPECTRAL) then
                  do l = 1, dim
                     lat(l) = 2.0_dp*pi*real(merge(m(l) - s%grid%n(l), m(l), 2*m(l) > s%grid%n(l)), dp)
                  end do
                  s%cosprod(i, j, k) = 1.0_dp
                  removed = nnyq >= 1
               else
                  cosprod = 1.0_dp
                  do l = 1, dim
                     cosprod = cosprod*ch(m(l), l)
                     lat(l) = 2.0_dp*s%grid%n(l)*sh(m(l), l)
                     do l2 = 1, dim
                        if (l2 /= l) lat(l) = lat(l)*ch(m(l2), l2)
                     end do
                  end do
                  s%cosprod(i, j, k) = cosprod
                  removed = nnyq >= 2
               end if
               removed = removed .or. all(m(1:dim) == 0)
               s%kv(:, i, j, k) = matmul(ait(1:dim, 1:dim), lat(1:dim))
               kk = sum(s%kv(:, i, j, k)**2)
               if (removed .or. kk <= 0.0_dp) then
                  ! kv = 0 too: every operator pass then leaves a removed mode at zero
                  ! without a branch in its loop (cg_apply_update)
                  s%ik2(i, j, k) = 0.0_dp
                  s%kv(:, i, j, k) = 0.0_dp
               else
                  s%ik2(i, j, k) = 1.0_dp/kk
               end if
            end do
         end do
      end do
      do l = 1, 3
         s%aith(:, l) = ait(:, l)*0.25_dp*real(s%grid%n(l), dp)
      end do
      s%lattice_set = .true.
   end subroutine stokes_fft_set_lattice

   !> Decide the stencil form (3-D, rotated finite differences, >= 1 z-plane on every
   !> rank: the halo exchange passes planes between neighbours) and allocate its tables.
   !> Collective over the transport's ranks.
   subroutine stencil_init(s)
      type(stokes_fft_t), intent(inout) :: s
      real(dp) :: ext(1)
      integer(ip) :: i, j, k, m(3), ny
      ext = [-real(s%fft%nl(3), dp)]
      call s%fft%max_all(ext)
      s%stencil = .false.
      s%stencil_ok = s%dim == 3 .and. s%set%derivative == FOLD_DERIV_FD .and. -ext(1) >= 1.0_dp
      if (.not. s%stencil_ok) return
      ny = s%fft%nl(2)
      allocate (s%ph1(s%fft%nxh), s%ph23(s%fft%nsl(2)*s%fft%nsl(3)))
      allocate (s%hfirst(s%fft%nxp, ny, 3), s%uhi(s%fft%nxp, ny, 3), s%fover(s%fft%nxp, ny, 3), &
                s%frecv(s%fft%nxp, ny, 3), s%hscr(s%fft%nxp, ny, 3), s%act(3, 0), s%dceta(0))
      s%hfirst = 0.0_dp
      s%uhi = 0.0_dp
      s%fover = 0.0_dp
      s%frecv = 0.0_dp
      s%hscr = 0.0_dp
      s%nact = 0
      ! i phase, phase = prod_l e^{i th_l / 2}, th_l = 2 pi m_l / n_l with m_l in [0, n_l)
      ! (the indices of the derivative tables of stokes_fft_set_lattice)
      do i = 1, s%fft%nxh
         s%ph1(i) = iu*exp(iu*pi*real(i - 1 + s%fft%soff(1), dp)/real(s%grid%n(s%fft%saxis(1)), dp))
      end do
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            m(s%fft%saxis) = [0_ip, j - 1, k - 1] + s%fft%soff
            s%ph23(j + (k - 1)*s%fft%nsl(2)) = exp(iu*pi*(real(m(s%fft%saxis(2)), dp)/ &
                                                          real(s%grid%n(s%fft%saxis(2)), dp) &
                                                          + real(m(s%fft%saxis(3)), dp)/ &
                                                          real(s%grid%n(s%fft%saxis(3)), dp)))
         end do
      end do
   end subroutine stencil_init

   !> Choose the form of this solve (s%stencil: the voxels with eta /= eta_f are at most
   !> stencil_fraction_max of the cell, counted over all ranks) and, for the stencil
   !> form, list them with 2 (eta - eta_f) / N (s%eta set). Grows the lists when needed
   !> (once per solve, never inside the iteration). Collective.
   subroutine stencil_active(s)
      type(stokes_fft_t), intent(inout) :: s
      integer(ip) :: i, j, k, n
      real(dp) :: c, frac(1)
      n = int(count(s%eta%r(1:s%grid%n(1), :, :) /= s%set%eta_f), ip)
      frac = [real(n, dp)]
      call s%fft%sum_all(frac)
      s%stencil = frac(1) <= s%stencil_fraction_max*real(grid_total(s%grid), dp)
      s%nact = 0
      if (.not. s%stencil) return
      if (size(s%dceta) < n) then
         deallocate (s%act, s%dceta)
         allocate (s%act(3, n + n/4), s%dceta(n + n/4))
      end if
      c = 2.0_dp/real(grid_total(s%grid), dp)
      n = 0
      do k = 1, s%grid%nl(3)
         do j = 1, s%grid%nl(2)
            do i = 1, s%grid%n(1)
               if (s%eta%r(i, j, k) /= s%set%eta_f) then
                  n = n + 1
                  s%act(:, n) = [i, j, k]
                  s%dceta(n) = c*(s%eta%r(i, j, k) - s%set%eta_f)
               end if
            end do
         end do
      end do
      s%nact = n
   end subroutine stencil_active

   !> Solve for u~ given chi (nx, n2l, n3l) at voxel centres and the mean velocity
   !> gradient G (G_ij = du_i/dx_j). FOLD_NOT_CONVERGED (message gives the
   !> residual reached) leaves the last iterate in s%x.
   subroutine stokes_fft_solve(s, chi, G, stat, errmsg)
      class(stokes_fft_t), intent(inout) :: s
      !> Solid volume fraction of each local voxel [-]
      real(dp), intent(in) :: chi(:, :, :)
      !> Mean velocity gradient [1/s]
      real(dp), intent(in) :: G(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: nx, it, dim
      real(dp) :: ext(2), red(2), bb, rz, rz_new, alpha, beta, pq, emin, emax

      call solve_begin(s, s%lattice_set, chi, G, "stokes_fft_solve", stat, errmsg)
      if (stat /= FOLD_OK) return
      nx = s%grid%n(1)
      dim = s%dim

      ! viscosity and the reference viscosity (geometric mean of the extremes)
      s%eta%r = 0.0_dp
      call penalty_viscosity(s%set, chi, s%eta%r(1:nx, :, :))
      emin = huge(1.0_dp)
      emax = 0.0_dp
      if (size(chi) > 0) then
         emin = minval(s%eta%r(1:nx, :, :))
         emax = maxval(s%eta%r(1:nx, :, :))
      end if
      ext = [-emin, emax]
      call s%fft%max_all(ext)
      s%eta0 = sqrt(-ext(1)*ext(2))

      s%ceta = (2.0_dp/real(grid_total(s%grid), dp))*s%eta%r
      if (s%single) s%eta_sp = real(s%ceta, c_float)
      if (s%stencil_ok) call stencil_active(s)

      ! right-hand side b = -P B^H (2 eta E), from one FFT of 2 eta
      call rhs(s, s%r)
      bb = precond_dot(s, s%r)
      ! the stencil form iterates on the unstaggered u^ = conj(i phase) u' (unitary per
      ! mode: P, M^-1 and every dot product are unchanged); s%x returns staggered
      if (s%stencil) call stagger(s, s%r, .false.)
      red = [bb, 0.0_dp]
      call s%fft%sum_all(red)
      bb = red(1)
      s%history = 0.0_dp
      s%iterations = 0
      if (bb <= 0.0_dp) then
         ! uniform viscosity: u~ = 0 exactly
         s%x = 0.0_dp
         s%residual = 0.0_dp
         s%have_guess = .true.
         s%have_prev = .false.
         return
      end if

      if (s%set%warm_start .and. s%have_guess) then
         if (s%set%guess == FOLD_GUESS_EXTRAPOLATE) then
            ! x <- 2 x_n - x_(n-1) (when there are two), x_prev <- x_n
            call extrapolate_guess(size(s%x, kind=i8), s%have_prev, s%x, s%x_prev)
            s%have_prev = .true.
         end if
         ! guess re-projected on this lattice's divergence-free modes
         call project(s, s%x)
         if (s%stencil) call stagger(s, s%x, .false.)
         ! r = b - A x by the passes of an iteration: p = x (direction update with z = 0
         ! and beta = 1), then r -= 1 A p, which also gives <r, M^-1 r>
         s%p = s%x
         call cg_direction_strain(s, 0.0_dp, 1.0_dp, 0.0_dp)
         call cg_stress(s, pq)
         red = [cg_apply_update(s, 1.0_dp), 0.0_dp]
      else
         s%x = 0.0_dp
         red = [precond_dot(s, s%r), 0.0_dp]
      end if
      ! Preconditioned CG (Hestenes-Stiefel form) with z = M^-1 r and q = A p never
      ! stored. Each iteration makes two passes over the spectrum and one over real
      ! space around the 2 ncg real FFTs: the direction update p = z + beta p and the
      ! deferred x += alpha p of the previous iteration ride on the strain pass
      ! (cg_direction_strain); <p, A p> = sum_x 2 eta eps(p):eps(p) (Parseval: p is
      ! divergence-free and zero on removed modes, so P drops out) is summed in real
      ! space by the viscosity pass (cg_viscous_energy), so that alpha is known before
      ! the operator pass, which then updates r -= alpha A p and sums <r, M^-1 r>
      ! without storing A p (cg_apply_update).
      call s%fft%sum_all(red)
      rz = red(1)
      ! the first direction update reads p (times beta = 0): it must be finite
      s%p = 0.0_dp
      s%residual = sqrt(max(rz, 0.0_dp)/bb)
      s%history(0) = s%residual
      it = 0
      alpha = 0.0_dp
      beta = 0.0_dp
      do while (s%residual > s%set%tol .and. it < s%set%max_iter)
         it = it + 1
         call cg_direction_strain(s, alpha, beta, 1.0_dp/s%eta0)
         call cg_stress(s, pq)
         if (.not. (pq > 0.0_dp)) then
            stat = FOLD_NUMERICAL
            write (errmsg, '(a,i0,a,es10.3)') "stokes_fft_solve: CG breakdown at iteration ", it, ", <p, A p> = ", pq
            s%iterations = it
            if (s%stencil) call stagger(s, s%x, .true.)
            return
         end if
         alpha = rz/pq
         red = [cg_apply_update(s, alpha), 0.0_dp]
         call s%fft%sum_all(red)
         rz_new = red(1)
         beta = rz_new/rz
         rz = rz_new
         s%residual = sqrt(max(rz, 0.0_dp)/bb)
         s%history(it) = s%residual
      end do
      ! the last step along p (deferred to the next direction update)
      if (it > 0) s%x = s%x + alpha*s%p
      if (s%stencil) call stagger(s, s%x, .true.)
      s%iterations = it
      s%have_guess = .true.
      call solve_verdict(s%set, "stokes_fft_solve", "CG", it, s%residual, stat, errmsg)
   end subroutine stokes_fft_solve

   !> u~ at the voxel centres into s%vel(1:dim)%r(1:nx, :, :) [m/s] (dim c2r FFTs).
   subroutine stokes_fft_velocity(s)
      class(stokes_fft_t), intent(inout) :: s
      integer(ip) :: c
      real(dp) :: scale
      scale = 1.0_dp/real(grid_total(s%grid), dp)
      do c = 1, s%dim
         ! corner velocities averaged to the centre: u^ avg = -i cosprod u' (staggered x)
         s%vel(c)%c = s%x(:, :, :, c)*((0.0_dp, -1.0_dp)*s%cosprod)
         call s%fft%c2r(s%vel(c))
         s%vel(c)%r = s%vel(c)%r*scale
      end do
   end subroutine stokes_fft_velocity

   !> Strain rate of u~ at the voxel centres into s%work(1:nc)%r(1:nx, :, :) [1/s]
   !> (components ci/cj; nc c2r FFTs).
   subroutine stokes_fft_strain(s)
      class(stokes_fft_t), intent(inout) :: s
      integer(ip) :: c
      real(dp) :: scale
      call strain(s, s%x)
      scale = 1.0_dp/real(grid_total(s%grid), dp)
      do c = 1, s%nc
         s%work(c)%r = s%work(c)%r*scale
      end do
   end subroutine stokes_fft_strain

   !> Release plans and storage.
   subroutine stokes_fft_destroy(s)
      class(stokes_fft_t), intent(inout) :: s
      call fields_free(s%work)
      call fields_free(s%vel)
      call field_free(s%eta)
      if (allocated(s%eta_sp)) deallocate (s%eta_sp)
      if (allocated(s%ceta)) deallocate (s%ceta)
      if (allocated(s%ph1)) deallocate (s%ph1, s%ph23, s%hfirst, s%uhi, s%fover, s%frecv, s%hscr, s%act, s%dceta)
      s%nact = 0
      s%stencil = .false.
      s%stencil_ok = .false.
      s%single = .false.
      if (allocated(s%fft)) then
         call s%fft%destroy()
         deallocate (s%fft)
      end if
      if (allocated(s%x)) deallocate (s%x, s%r, s%p, s%q)
      if (allocated(s%x_prev)) deallocate (s%x_prev)
      if (allocated(s%kv)) deallocate (s%kv, s%ik2, s%cosprod)
      if (allocated(s%wx)) deallocate (s%wx)
      if (allocated(s%history)) deallocate (s%history)
      s%have_guess = .false.
      s%have_prev = .false.
      s%lattice_set = .false.
   end subroutine stokes_fft_destroy

   function fft_velocity_field(s, c) result(f)
      class(stokes_fft_t), intent(in) :: s
      integer(ip), intent(in) :: c
      real(dp), pointer, contiguous :: f(:, :, :)
      f => s%vel(c)%r
   end function fft_velocity_field

   function fft_strain_field(s, c) result(f)
      class(stokes_fft_t), intent(in) :: s
      integer(ip), intent(in) :: c
      real(dp), pointer, contiguous :: f(:, :, :)
      f => s%work(c)%r
   end function fft_strain_field

   function fft_viscosity_field(s) result(f)
      class(stokes_fft_t), intent(in) :: s
      real(dp), pointer, contiguous :: f(:, :, :)
      f => s%eta%r
   end function fft_viscosity_field

   subroutine fft_sum_all(s, x)
      class(stokes_fft_t), intent(in) :: s
      real(dp), intent(inout) :: x(:)
      call s%fft%sum_all(x)
   end subroutine fft_sum_all

   subroutine fft_max_all(s, x)
      class(stokes_fft_t), intent(in) :: s
      real(dp), intent(inout) :: x(:)
      call s%fft%max_all(x)
   end subroutine fft_max_all

   !> Relative preconditioned residual sqrt(<b - A x, M^-1 (b - A x)> / <b, M^-1 b>) of
   !> the last solution, with the double-precision operator whatever fft_precision is
   !> (the recursive residual of a single-precision solve can sink below what its
   !> iterate attains). Overwrites the CG vectors r and q; call after a solve.
   function stokes_fft_true_residual(s) result(res)
      class(stokes_fft_t), intent(inout) :: s
      real(dp) :: res
      real(dp) :: red(2)
      call rhs(s, s%r)
      call apply(s, s%x, s%q)
      red(1) = precond_dot(s, s%r)
      s%r = s%r - s%q
      red(2) = precond_dot(s, s%r)
      call s%fft%sum_all(red)
      res = 0.0_dp
      if (red(1) > 0.0_dp) res = sqrt(max(red(2), 0.0_dp)/red(1))
   end function stokes_fft_true_residual

   !> au = A u in double precision (u a divergence-free Fourier field of the layout of
   !> s%x, zero on removed modes; the unnormalised scale of stokes_fft_solve).
   subroutine stokes_fft_apply(s, u, au)
      class(stokes_fft_t), intent(inout) :: s
      complex(dp), intent(in) :: u(:, :, :, :)
      complex(dp), intent(out) :: au(:, :, :, :)
      call apply(s, u, au)
   end subroutine stokes_fft_apply

   !> au = A u by the CG iteration's own passes: the stencil form when s%stencil, the
   !> transforms in the settings' precision (u as for stokes_fft_apply). Overwrites the
   !> CG vectors p and r; for tests of the passes against stokes_fft_apply.
   subroutine stokes_fft_apply_cg(s, u, au)
      class(stokes_fft_t), intent(inout) :: s
      complex(dp), intent(in) :: u(:, :, :, :)
      complex(dp), intent(out) :: au(:, :, :, :)
      real(dp) :: pq, rz
      s%p = u
      if (s%stencil) call stagger(s, s%p, .false.)
      s%r = 0.0_dp
      ! p <- 0 M^-1 r + 1 p = u (and x += 0 p)
      call cg_direction_strain(s, 0.0_dp, 1.0_dp, 0.0_dp)
      call cg_stress(s, pq)
      s%r = 0.0_dp
      rz = cg_apply_update(s, -1.0_dp)
      if (s%stencil) call stagger(s, s%r, .true.)
      au = s%r
   end subroutine stokes_fft_apply_cg

   !> Remove the divergent part and the excluded modes of a Fourier field (layout of s%x).
   subroutine stokes_fft_project(s, u)
      class(stokes_fft_t), intent(in) :: s
      complex(dp), intent(inout) :: u(:, :, :, :)
      call project(s, u)
   end subroutine stokes_fft_project

   !> Smallest tolerance accepted with single-precision transforms on a grid of nvox
   !> voxels: (2 log2 nvox + 4) u_s (module header: the attainable residual).
   pure function single_tol_min(nvox) result(t)
      integer(i8), intent(in) :: nvox
      real(dp) :: t
      t = FOLD_SINGLE_ROUNDOFF*(2.0_dp*log(real(max(nvox, 2_i8), dp))/log(2.0_dp) + 4.0_dp)
   end function single_tol_min

   ! ------------------------------------------------------------------ internals

   !> Right-hand side b = -P B^H (2 eta E) from one FFT of 2 eta (s%eta, s%E set).
   subroutine rhs(s, b)
      type(stokes_fft_t), intent(inout) :: s
      complex(dp), intent(out) :: b(:, :, :, :)
      integer(ip) :: i, j, k, dim
      complex(dp) :: f(3)
      dim = s%dim
      s%work(1)%r = 2.0_dp*s%eta%r
      call s%fft%r2c(s%work(1))
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            do i = 1, s%fft%nxh
               if (s%ik2(i, j, k) == 0.0_dp) then
                  b(i, j, k, :) = 0.0_dp
                  cycle
               end if
               ! staggered: i phase (-conj(d)_j E_ij (2eta)^) = -kv_j E_ij (2eta)^
               f(1:dim) = -matmul(s%E(1:dim, 1:dim), s%kv(:, i, j, k))*s%work(1)%c(i, j, k)
               f(1:dim) = f(1:dim) - s%kv(:, i, j, k)*sum(s%kv(:, i, j, k)*f(1:dim))*s%ik2(i, j, k)
               b(i, j, k, :) = f(1:dim)
            end do
         end do
      end do
   end subroutine rhs

   !> Strain of the Fourier field u into work(:)%r, normalised.
   subroutine strain(s, u)
      type(stokes_fft_t), intent(inout) :: s
      complex(dp), intent(in) :: u(:, :, :, :)
      integer(ip) :: i, j, k, c
      real(dp) :: d(3)
      complex(dp) :: uu(3)
      ! staggered variable: B u = sym(kv (x) u')
      if (s%dim == 3) then
         do k = 1, s%fft%nsl(3)
            do j = 1, s%fft%nsl(2)
               do i = 1, s%fft%nxh
                  d(1) = s%kv(1, i, j, k)
                  d(2) = s%kv(2, i, j, k)
                  d(3) = s%kv(3, i, j, k)
                  uu(1) = u(i, j, k, 1)
                  uu(2) = u(i, j, k, 2)
                  uu(3) = u(i, j, k, 3)
                  s%work(1)%c(i, j, k) = d(1)*uu(1)
                  s%work(2)%c(i, j, k) = d(2)*uu(2)
                  s%work(3)%c(i, j, k) = d(3)*uu(3)
                  s%work(4)%c(i, j, k) = 0.5_dp*(d(1)*uu(2) + d(2)*uu(1))
                  s%work(5)%c(i, j, k) = 0.5_dp*(d(1)*uu(3) + d(3)*uu(1))
                  s%work(6)%c(i, j, k) = 0.5_dp*(d(2)*uu(3) + d(3)*uu(2))
               end do
            end do
         end do
      else
         do k = 1, s%fft%nsl(3)
            do j = 1, s%fft%nsl(2)
               do i = 1, s%fft%nxh
                  d(1) = s%kv(1, i, j, k)
                  d(2) = s%kv(2, i, j, k)
                  uu(1) = u(i, j, k, 1)
                  uu(2) = u(i, j, k, 2)
                  s%work(1)%c(i, j, k) = d(1)*uu(1)
                  s%work(2)%c(i, j, k) = d(2)*uu(2)
                  s%work(3)%c(i, j, k) = 0.5_dp*(d(1)*uu(2) + d(2)*uu(1))
               end do
            end do
         end do
      end if
      do c = 1, s%nc
         call s%fft%c2r(s%work(c))
      end do
   end subroutine strain

   !> A u = P B^H (2 eta B u) (u divergence-free, removed modes zero).
   subroutine apply(s, u, au)
      type(stokes_fft_t), intent(inout) :: s
      complex(dp), intent(in) :: u(:, :, :, :)
      complex(dp), intent(out) :: au(:, :, :, :)
      integer(ip) :: i, j, k, c, nx
      real(dp) :: dc(3)
      complex(dp) :: f(3)
      real(dp) :: two_over_n
      call strain(s, u)
      nx = s%grid%n(1)
      ! strain() leaves the unnormalised c2r: 1/N folds into the viscosity pass
      two_over_n = 2.0_dp/real(grid_total(s%grid), dp)
      do c = 1, s%nc
         s%work(c)%r(1:nx, :, :) = (two_over_n*s%eta%r(1:nx, :, :))*s%work(c)%r(1:nx, :, :)
         call s%fft%r2c(s%work(c))
      end do
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            do i = 1, s%fft%nxh
               if (s%ik2(i, j, k) == 0.0_dp) then
                  au(i, j, k, :) = 0.0_dp
                  cycle
               end if
               ! staggered: (B^H sigma)' = kv . sigma
               dc(1:s%dim) = s%kv(:, i, j, k)
               if (s%dim == 3) then
                  f(1) = dc(1)*s%work(1)%c(i, j, k) + dc(2)*s%work(4)%c(i, j, k) + dc(3)*s%work(5)%c(i, j, k)
                  f(2) = dc(1)*s%work(4)%c(i, j, k) + dc(2)*s%work(2)%c(i, j, k) + dc(3)*s%work(6)%c(i, j, k)
                  f(3) = dc(1)*s%work(5)%c(i, j, k) + dc(2)*s%work(6)%c(i, j, k) + dc(3)*s%work(3)%c(i, j, k)
               else
                  f(1) = dc(1)*s%work(1)%c(i, j, k) + dc(2)*s%work(3)%c(i, j, k)
                  f(2) = dc(1)*s%work(3)%c(i, j, k) + dc(2)*s%work(2)%c(i, j, k)
               end if
               f(1:s%dim) = f(1:s%dim) - s%kv(:, i, j, k)*sum(s%kv(:, i, j, k)*f(1:s%dim))*s%ik2(i, j, k)
               au(i, j, k, :) = f(1:s%dim)
            end do
         end do
      end do
   end subroutine apply

   !> Remove the divergent part and the excluded modes of a Fourier field.
   subroutine project(s, u)
      type(stokes_fft_t), intent(in) :: s
      complex(dp), intent(inout) :: u(:, :, :, :)
      integer(ip) :: i, j, k
      complex(dp) :: f(3)
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            do i = 1, s%fft%nxh
               if (s%ik2(i, j, k) == 0.0_dp) then
                  u(i, j, k, :) = 0.0_dp
               else
                  f(1:s%dim) = u(i, j, k, :)
                  f(1:s%dim) = f(1:s%dim) - s%kv(:, i, j, k)*sum(s%kv(:, i, j, k)*f(1:s%dim))*s%ik2(i, j, k)
                  u(i, j, k, :) = f(1:s%dim)
               end if
            end do
         end do
      end do
   end subroutine project

   !> u <- i phase u (to_staggered) or conj(i phase) u, per mode (stencil form's tables).
   subroutine stagger(s, u, to_staggered)
      type(stokes_fft_t), intent(in) :: s
      complex(dp), intent(inout) :: u(:, :, :, :)
      logical, intent(in) :: to_staggered
      integer(ip) :: i, j, k, c
      complex(dp) :: ph
      do c = 1, s%dim
         do k = 1, s%fft%nsl(3)
            do j = 1, s%fft%nsl(2)
               do i = 1, s%fft%nxh
                  ph = s%ph1(i)*s%ph23(j + (k - 1)*s%fft%nsl(2))
                  if (.not. to_staggered) ph = conjg(ph)
                  u(i, j, k, c) = ph*u(i, j, k, c)
               end do
            end do
         end do
      end do
   end subroutine stagger

   !> Local <r, M^-1 r> (not yet summed over ranks).
   function precond_dot(s, r) result(v)
      type(stokes_fft_t), intent(in) :: s
      complex(dp), intent(in) :: r(:, :, :, :)
      real(dp) :: v
      integer(ip) :: i, j, k, c
      v = 0.0_dp
      do c = 1, s%dim
         do k = 1, size(r, 3)
            do j = 1, size(r, 2)
               do i = 1, size(r, 1)
                  v = v + s%wx(i)*s%ik2(i, j, k)*(real(r(i, j, k, c))**2 + aimag(r(i, j, k, c))**2)
               end do
            end do
         end do
      end do
      v = v/s%eta0
   end function precond_dot

   !> Initial guess by linear extrapolation in time: with x = x_n and xp = x_(n-1),
   !> x <- 2 x_n - x_(n-1) and xp <- x_n in one pass; without a second solution
   !> (have_prev false) x is kept and xp <- x_n.
   subroutine extrapolate_guess(n, have_prev, x, xp)
      integer(i8), intent(in) :: n
      logical, intent(in) :: have_prev
      complex(dp), intent(inout) :: x(n), xp(n)
      integer(i8) :: m
      complex(dp) :: xn
      if (have_prev) then
         do m = 1, n
            xn = x(m)
            x(m) = 2.0_dp*xn - xp(m)
            xp(m) = xn
         end do
      else
         xp = x
      end if
   end subroutine extrapolate_guess

   ! ------------------------------------------------------------------ CG passes
   ! (the kernels: fortran/stokes/fold_cg_kernels.f90.in)

   !> x += a_prev p_old; p = zs eta0 M^-1 r + beta p_old (zs = 1/eta0: the CG direction);
   !> then what the operator pass transforms: the velocity of p on the corner grid into
   !> vel(1:3)%c (stencil form), else the strain of p into the spectral views of
   !> work(cg_comp) (single ones if s%single).
   subroutine cg_direction_strain(s, a_prev, beta, zs)
      type(stokes_fft_t), intent(inout), target :: s
      real(dp), intent(in) :: a_prev, beta, zs
      integer(ip) :: nxh, njk
      nxh = s%fft%nxh
      njk = s%fft%nsl(2)*s%fft%nsl(3)
      if (s%stencil) then
         s%e_uniform = s%set%eta_f* &
                       direction_velocity3(nxh, njk, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3), &
                                           s%p(:, :, :, 1), s%p(:, :, :, 2), s%p(:, :, :, 3), s%x(:, :, :, 1), &
                                           s%x(:, :, :, 2), s%x(:, :, :, 3), s%kv, s%ik2, s%wx, zs, a_prev, beta, &
                                           s%vel(1)%c, s%vel(2)%c, s%vel(3)%c)
      else if (s%single .and. s%dim == 3) then
         call direction_strain3_sp(nxh*njk, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3), s%p(:, :, :, 1), &
                                   s%p(:, :, :, 2), s%p(:, :, :, 3), s%x(:, :, :, 1), s%x(:, :, :, 2), &
                                   s%x(:, :, :, 3), s%kv, s%ik2, zs, a_prev, beta, &
                                   s%work(1)%cs, s%work(2)%cs, s%work(4)%cs, s%work(5)%cs, s%work(6)%cs)
      else if (s%single) then
         call direction_strain2_sp(nxh*njk, s%r(:, :, :, 1), s%r(:, :, :, 2), s%p(:, :, :, 1), s%p(:, :, :, 2), &
                                   s%x(:, :, :, 1), s%x(:, :, :, 2), s%kv, s%ik2, zs, a_prev, beta, &
                                   s%work(1)%cs, s%work(3)%cs)
      else if (s%dim == 3) then
         call direction_strain3(nxh*njk, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3), s%p(:, :, :, 1), &
                                s%p(:, :, :, 2), s%p(:, :, :, 3), s%x(:, :, :, 1), s%x(:, :, :, 2), &
                                s%x(:, :, :, 3), s%kv, s%ik2, zs, a_prev, beta, &
                                s%work(1)%c, s%work(2)%c, s%work(4)%c, s%work(5)%c, s%work(6)%c)
      else
         call direction_strain2(nxh*njk, s%r(:, :, :, 1), s%r(:, :, :, 2), s%p(:, :, :, 1), s%p(:, :, :, 2), &
                                s%x(:, :, :, 1), s%x(:, :, :, 2), s%kv, s%ik2, zs, a_prev, beta, &
                                s%work(1)%c, s%work(3)%c)
      end if
   end subroutine cg_direction_strain

   !> The stress of p, back in Fourier space, and pq = <p, A p> summed over ranks.
   !> Stencil form: 3 c2r of the corner velocity (double), the stencil pass (strain,
   !> 2 eta, <p, A p>, force at the corners, stencil_force), 3 r2c of the force into
   !> work(1:3). Spectral form: ncg c2r of the strain, the viscosity pass, ncg r2c of the
   !> stress. Both unnormalised like the strain (the 1/N folds into ceta = 2 eta / N).
   subroutine cg_stress(s, pq)
      type(stokes_fft_t), intent(inout) :: s
      real(dp), intent(out) :: pq
      integer(ip) :: c
      real(dp) :: red(2)
      if (s%stencil) then
         do c = 1, 3
            call s%fft%c2r(s%vel(c))
         end do
         red = [stencil_pass(s), 0.0_dp]
         do c = 1, 3
            call s%fft%transform(s%work(c), .true., s%single)
         end do
      else
         do c = 1, s%ncg
            call s%fft%transform(s%work(s%cg_comp(c)), .false., s%single)
         end do
         ! times 2 eta (the 1/N of the unnormalised c2r folds in); <p, A p> on the way
         red = [cg_viscous_energy(s), 0.0_dp]
         do c = 1, s%ncg
            call s%fft%transform(s%work(s%cg_comp(c)), .true., s%single)
         end do
      end if
      call s%fft%sum_all(red)
      pq = red(1)
   end subroutine cg_stress

   !> The stencil pass on the corner velocity in vel(1:3)%r: the next rank's first
   !> corner plane in, the corner force of the non-uniform viscosity into work(1:3)
   !> (%rs if s%single; zero away from the particles), the force on the corner plane after
   !> the slab out to the next rank; returns the local <p, A p> (uniform part included).
   function stencil_pass(s) result(pq)
      type(stokes_fft_t), intent(inout) :: s
      real(dp) :: pq
      integer(ip) :: c, nx, nz
      nx = s%grid%n(1)
      nz = s%grid%nl(3)
      do c = 1, 3
         s%hfirst(:, :, c) = s%vel(c)%r(:, :, 1)
      end do
      call s%fft%z_halo(size(s%hfirst, kind=i8), s%hfirst, s%hfirst, s%hscr, s%uhi)
      s%fover = 0.0_dp
      if (s%single) then
         do c = 1, 3
            s%work(c)%rs(1:nx, :, :) = 0.0
         end do
         call stencil_force_sp(nx, s%fft%nxp, s%grid%nl(2), nz, s%aith, s%vel(1)%r, s%vel(2)%r, s%vel(3)%r, &
                               s%uhi, s%nact, s%act, s%dceta, s%work(1)%rs, s%work(2)%rs, s%work(3)%rs, s%fover, pq)
      else
         do c = 1, 3
            s%work(c)%r(1:nx, :, :) = 0.0_dp
         end do
         call stencil_force(nx, s%fft%nxp, s%grid%nl(2), nz, s%aith, s%vel(1)%r, s%vel(2)%r, s%vel(3)%r, &
                            s%uhi, s%nact, s%act, s%dceta, s%work(1)%r, s%work(2)%r, s%work(3)%r, s%fover, pq)
      end if
      ! the force on the corner plane after the slab belongs to the next rank's first
      call s%fft%z_halo(size(s%fover, kind=i8), s%fover, s%fover, s%frecv, s%hscr)
      do c = 1, 3
         if (s%single) then
            s%work(c)%rs(1:nx, :, 1) = real(s%work(c)%rs(1:nx, :, 1) + s%frecv(1:nx, :, c), c_float)
         else
            s%work(c)%r(1:nx, :, 1) = s%work(c)%r(1:nx, :, 1) + s%frecv(1:nx, :, c)
         end if
      end do
      pq = pq + s%e_uniform
   end function stencil_pass

   !> work(cg_comp)%r <- ceta work(cg_comp)%r on the nx data columns (the strain of p,
   !> unnormalised c2r, becomes the stress; ceta = 2 eta / N); returns the local
   !> <p, A p> = sum_x ceta E:E with the full (traceless) 3 x 3 (2 x 2) Frobenius
   !> product, E the strain field as transformed.
   function cg_viscous_energy(s) result(pq)
      type(stokes_fft_t), intent(inout), target :: s
      real(dp) :: pq
      integer(ip) :: nrows
      nrows = s%grid%nl(2)*s%grid%nl(3)
      if (s%single .and. s%dim == 3) then
         pq = viscous_energy3_sp(s%grid%n(1), s%fft%nxp, nrows, s%eta_sp, s%work(1)%rs, s%work(2)%rs, &
                                 s%work(4)%rs, s%work(5)%rs, s%work(6)%rs)
      else if (s%single) then
         pq = viscous_energy2_sp(s%grid%n(1), s%fft%nxp, nrows, s%eta_sp, s%work(1)%rs, s%work(3)%rs)
      else if (s%dim == 3) then
         pq = viscous_energy3(s%grid%n(1), s%fft%nxp, nrows, s%ceta, s%work(1)%r, s%work(2)%r, &
                              s%work(4)%r, s%work(5)%r, s%work(6)%r)
      else
         pq = viscous_energy2(s%grid%n(1), s%fft%nxp, nrows, s%ceta, s%work(1)%r, s%work(3)%r)
      end if
   end function cg_viscous_energy

   !> r -= alpha P B^H (stress in work(1:nc)%c) (zero on removed modes), or in the
   !> stencil form r -= alpha P f' (force in work(1:3)%c); returns the local <r, M^-1 r>.
   function cg_apply_update(s, alpha) result(rz)
      type(stokes_fft_t), intent(inout), target :: s
      real(dp), intent(in) :: alpha
      real(dp) :: rz
      integer(ip) :: nxh, njk
      nxh = s%fft%nxh
      njk = s%fft%nsl(2)*s%fft%nsl(3)
      if (s%stencil .and. s%single) then
         rz = stencil_update3_sp(nxh, njk, s%work(1)%cs, s%work(2)%cs, s%work(3)%cs, s%p(:, :, :, 1), &
                                 s%p(:, :, :, 2), s%p(:, :, :, 3), s%set%eta_f, s%kv, s%ik2, &
                                 s%wx, alpha, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3))
      else if (s%stencil) then
         rz = stencil_update3(nxh, njk, s%work(1)%c, s%work(2)%c, s%work(3)%c, s%p(:, :, :, 1), &
                              s%p(:, :, :, 2), s%p(:, :, :, 3), s%set%eta_f, s%kv, s%ik2, &
                              s%wx, alpha, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3))
      else if (s%single .and. s%dim == 3) then
         rz = apply_update3_sp(nxh, njk, s%work(1)%cs, s%work(2)%cs, s%work(4)%cs, s%work(5)%cs, s%work(6)%cs, &
                               s%kv, s%ik2, s%wx, alpha, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3))
      else if (s%single) then
         rz = apply_update2_sp(nxh, njk, s%work(1)%cs, s%work(3)%cs, s%kv, s%ik2, s%wx, alpha, s%r(:, :, :, 1), &
                               s%r(:, :, :, 2))
      else if (s%dim == 3) then
         rz = apply_update3(nxh, njk, s%work(1)%c, s%work(2)%c, s%work(4)%c, s%work(5)%c, s%work(6)%c, &
                            s%kv, s%ik2, s%wx, alpha, s%r(:, :, :, 1), s%r(:, :, :, 2), s%r(:, :, :, 3))
      else
         rz = apply_update2(nxh, njk, s%work(1)%c, s%work(3)%c, s%kv, s%ik2, s%wx, alpha, s%r(:, :, :, 1), &
                           s%r(:, :, :, 2))
      end if
      rz = rz/s%eta0
   end function cg_apply_update

end module fold_stokes_fft
