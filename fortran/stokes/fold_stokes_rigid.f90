!> Exact-rigidity Stokes solve on the periodic (skewed) cell: the constraint
!> eps(u) = 0 in the solid imposed by a multiplier instead of a penalty.
!>
!> The penalised solve (fold_stokes_fft) regularises the constraint with a viscosity
!> kappa eta_f in the solid; its CG count grows like sqrt(kappa) and its particles keep a
!> strain of order 1/kappa times the stress they carry, which for a fibre of aspect ratio
!> beta is ~ beta^2 / ln beta times the imposed rate (docs/physics.md#exact-rigidity).
!> Here the fluid viscosity is eta_f everywhere (the fictitious domain extends the fluid
!> into the particles) and a symmetric, traceless multiplier lambda [Pa] lives on the
!> solid voxels, those covered at least half (chi >= FOLD_RIGID_COVERAGE; every corner of
!> a solid voxel then moves rigidly). The stress is sigma = 2 eta_f eps(u) + chi_s lambda - p I, and
!> u = G x + u~ solves
!>     -div(2 eta_f eps(u~)) + grad p = div(chi_s lambda),  div u~ = 0,
!>     chi_s (E + eps(u~)) = 0                                   (rigidity),
!> the rigidity constraint D(u) = 0 with a stress-like multiplier of Patankar, Singh,
!> Joseph, Glowinski & Pan (2000, Int. J. Multiphase Flow 26:1509). With the uniform
!> fluid, u~ = -A^-1 P B^H (chi_s lambda), A = eta_f |kv|^2 on the divergence-free
!> modes (the Green operator of the FFT solver, exact and diagonal in Fourier space),
!> and the multiplier solves the Schur-complement system
!>     S lambda = chi_s E,   S = chi_s B A^-1 P B^H chi_s,
!> symmetric positive semi-definite in the Frobenius product (its null space, the
!> self-equilibrated stresses inside a body, never enters the CG iterates started from a
!> guess in its range, and does not change u~). CG on it needs no kappa: the spectrum of
!> S lies in [0, 1/(2 eta_f)] and is set by the geometry alone. The residual
!> r = chi_s E - S lambda = chi_s (E + eps(u~)) is the strain left inside the particles,
!> so the solver tolerance is the rigidity error: ||r|| / ||chi_s E|| <= tol.
!> Partly covered voxels. A voxel covered less than half is not rigid: it takes the
!> kappa -> infinity limit of the penalised solve's default (harmonic) mixing,
!> eta_f / (1 - chi) <= 2 eta_f, whose stress 2 (eta - eta_f) eps is a polarisation tau = D eps with
!> D = 2 eta_f chi / (1 - chi). Listing those voxels with the solid ones, the unknown is
!> the polarisation on every voxel the particles touch, and with Gamma = B A^-1 P B^H,
!>     (Gamma + C) tau = E,   C = D^-1 on the partly covered voxels, 0 on the solid ones,
!> still symmetric positive semi-definite (C adds a diagonal >= 1/(2 eta_f)); on the
!> solid voxels it is the rigidity constraint above, on the others tau = D (E - Gamma tau).
!> The partial voxels move the particle's surface smoothly with its position (a binary
!> solid jumps by whole voxels). On a binary chi the penalised solve is this system with
!> 1/(2 eta_f (kappa - 1)) added on the solid voxels, a Tikhonov regularisation: its
!> eta_eff lies below this one's and approaches it like 1/kappa
!> (tests/micro/test_stokes_exact.py). With partial volumes the two are different
!> discretisations of the surface (the penalty's harmonic mixing leaves every partly
!> covered voxel soft), which differ at first order in the voxel size
!> (docs/physics.md#exact-rigidity). The residual over all these voxels is at
!> most tol ||E|| sqrt(N_touched), so the strain left on the solid voxels relative to E
!> is at most tol sqrt(N_touched / N_solid).
!> Net force and torque on each body vanish by construction (the force density is the
!> divergence of a symmetric stress supported on the body), so the free rigid motion is
!> the velocity of the solution inside the body; rigid_fit reads it with weight 1 on the
!> solid voxels and 0 elsewhere. The bulk stress is 2 eta_f E + <chi_s lambda>.
!>
!> One iteration, stencil form (3-D rotated differences, the default): the direction's
!> corner force scattered in real space from the listed voxels, 3 r2c transforms, the
!> Green operator per mode, 3 c2r transforms of the corner velocity, the strain gathered
!> at the listed voxels: 6 real FFTs. Spectral form (spectral derivatives, 2-D): the ncg
!> independent stress components forward and strain components back, 10 FFTs (4 in 2-D). The velocity of
!> the solution accumulates in Fourier space along the iterations (x += alpha q), so no
!> transform is spent on it. Warm start: the multiplier of the previous solve at the
!> voxels that were and are solid (a real-space field, unaffected by the change of
!> lattice); zero on the partly covered ones, whose compliance moves with the coverage.
!> Works serially and over FFTW-MPI slabs (every operation is local to the slab except
!> the transforms and the dot products).
module fold_stokes_rigid
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NUMERICAL
   use fold_penalty, only: solve_begin, solve_verdict
   use fold_fft_transport, only: fft_transport_t
   use fold_grid, only: grid_total
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, FOLD_FFT_DOUBLE, FOLD_RIGID_COVERAGE
   use fold_stokes_fft, only: stokes_fft_t, stokes_fft_init, stokes_fft_destroy
   implicit none
   private

   !> Exact-rigidity solver: the FFT solver's grid, plans, per-mode tables and outputs,
   !> with its own solve.
   type, extends(stokes_fft_t), public :: stokes_rigid_t
      !> Local solid voxels (i, j, k) of this solve; nsol of the capacity in use
      integer(ip), allocatable :: sol(:, :)
      integer(ip) :: nsol = 0
      !> The compliance of each listed voxel, 1 / (2 (eta - eta_f)) with the harmonic
      !> mixing's kappa -> infinity viscosity eta = eta_f / (1 - chi) where chi < 1/2, and 0
      !> on the solid voxels (chi >= FOLD_RIGID_COVERAGE, rigid) [1/(Pa s)]
      real(dp), allocatable :: comp(:)
      !> Multiplier, residual, direction and S applied to the direction on the solid
      !> voxels, in the ncg independent components (3-D: 11, 22, 12, 13, 23) [Pa, 1/s]
      real(dp), allocatable :: lam(:, :), res(:, :), dir(:, :), sdir(:, :)
      !> Multiplier of the last solve as fields (ncg, nx, local y, local z), zero off the
      !> solid: the warm start of the next solve
      real(dp), allocatable :: lam_field(:, :, :, :)
   contains
      procedure :: solve => stokes_rigid_solve
      procedure :: destroy => stokes_rigid_destroy
   end type stokes_rigid_t

   public :: stokes_rigid_new

contains

   !> An exact-rigidity solver seen through the abstract type (stokes_fft_init on a new
   !> object); on failure solver stays unallocated and errmsg names the setting.
   subroutine stokes_rigid_new(fft, set, solver, stat, errmsg)
      !> Transport; moved into the solver (deallocated on return)
      class(fft_transport_t), allocatable, intent(inout) :: fft
      type(stokes_settings_t), intent(in) :: set
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(stokes_rigid_t), allocatable :: s
      if (set%fft_precision /= FOLD_FFT_DOUBLE) then
         stat = FOLD_INPUT_ERROR
         errmsg = "stokes settings: rigidity exact transforms in double precision only; "// &
                  "set fft_precision double (or rigidity penalty)"
         return
      end if
      allocate (s)
      call stokes_fft_init(s%stokes_fft_t, fft, set, stat, errmsg)
      if (stat /= FOLD_OK) then
         call s%destroy()
         return
      end if
      s%exact_rigidity = .true.
      allocate (s%sol(3, 0), s%comp(0), s%lam(s%ncg, 0), s%res(s%ncg, 0), s%dir(s%ncg, 0), s%sdir(s%ncg, 0))
      allocate (s%lam_field(s%ncg, s%grid%n(1), s%grid%nl(2), s%grid%nl(3)))
      s%lam_field = 0.0_dp
      call move_alloc(s, solver)
   end subroutine stokes_rigid_new

   subroutine stokes_rigid_destroy(s)
      class(stokes_rigid_t), intent(inout) :: s
      if (allocated(s%sol)) deallocate (s%sol, s%comp, s%lam, s%res, s%dir, s%sdir)
      if (allocated(s%lam_field)) deallocate (s%lam_field)
      s%nsol = 0
      call stokes_fft_destroy(s%stokes_fft_t)
   end subroutine stokes_rigid_destroy

   !> Solve for u~ and the multiplier given chi (nx, n2l, n3l) and G. FOLD_NOT_CONVERGED
   !> (the message gives the rigidity error reached) keeps the last iterate.
   subroutine stokes_rigid_solve(s, chi, G, stat, errmsg)
      class(stokes_rigid_t), intent(inout) :: s
      !> Solid volume fraction of each local voxel [-] and mean velocity gradient [1/s]
      real(dp), intent(in) :: chi(:, :, :), G(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: nx, it, v
      real(dp) :: red(2), bb, rr, rz, alpha, beta, pq, eb(5)

      call solve_begin(s, s%lattice_set, chi, G, "stokes_rigid_solve", stat, errmsg)
      if (stat /= FOLD_OK) return
      nx = s%grid%n(1)
      ! the fluid fills the cell; the particles' stress is the polarisation's (on the partly
      ! covered voxels too: 2 (eta - eta_f) eps from the strain would amplify the CG error
      ! of eps there by eta / eta_f)
      s%eta%r = s%set%eta_f
      s%multiplier_stress = 0.0_dp
      ! the stencil form wherever it exists (3-D rotated differences, >= 1 z-plane per
      ! rank); a negative stencil_fraction_max asks for the spectral form (tests)
      s%stencil = s%stencil_ok .and. s%stencil_fraction_max >= 0.0_dp
      call solid_list(s, chi)
      eb = reduced(s, s%E)

      ! b = chi_s E on the solid voxels
      s%history = 0.0_dp
      s%iterations = 0
      bb = real(s%nsol, dp)*frob(s, eb, eb)
      red = [bb, 0.0_dp]
      call s%fft%sum_all(red)
      bb = red(1)
      s%x = 0.0_dp
      if (bb <= 0.0_dp) then
         ! no solid voxel, or no imposed strain: u~ = 0 exactly
         s%residual = 0.0_dp
         s%lam_field = 0.0_dp
         s%have_guess = .true.
         return
      end if

      ! guess: the previous multiplier where the voxel is still solid (lam_field holds the
      ! solid voxels' only). A partly covered voxel starts from zero: its compliance changes
      ! with the coverage, (1 - chi) / (2 eta_f chi) -> infinity as chi -> 0, so a
      ! multiplier carried over onto it leaves a residual C lambda without bound (10^9 times
      ! ||E|| seen on dense fibres, where the zero start has 1).
      do v = 1, s%nsol
         if (s%set%warm_start .and. s%have_guess .and. s%comp(v) == 0.0_dp) then
            s%lam(:, v) = s%lam_field(:, s%sol(1, v), s%sol(2, v), s%sol(3, v))
         else
            s%lam(:, v) = 0.0_dp
         end if
         s%res(:, v) = eb
      end do
      red = [sum(abs(s%lam(:, 1:s%nsol))), 0.0_dp]
      call s%fft%sum_all(red)
      if (red(1) > 0.0_dp) then
         ! r = b - S lambda0; the velocity of lambda0 starts the accumulator
         s%dir(:, 1:s%nsol) = s%lam(:, 1:s%nsol)
         call apply_schur(s)
         s%x = s%q
         s%res(:, 1:s%nsol) = s%res(:, 1:s%nsol) - s%sdir(:, 1:s%nsol)
      end if
      ! Jacobi-preconditioned CG: z = W r, W = g0 / (g0 + C) per voxel, g0 the mean diagonal of
      ! Gamma (1 on the solid voxels; it rescales the stiff, nearly empty partial voxels)
      call precondition(s, s%res, s%dir)
      red = [dot_list(s, s%res, s%res), dot_list(s, s%res, s%dir)]
      call s%fft%sum_all(red)
      rr = red(1)
      rz = red(2)
      s%residual = sqrt(max(rr, 0.0_dp)/bb)
      s%history(0) = s%residual
      it = 0
      do while (s%residual > s%set%tol .and. it < s%set%max_iter)
         it = it + 1
         call apply_schur(s)
         red = [dot_list(s, s%dir, s%sdir), 0.0_dp]
         call s%fft%sum_all(red)
         pq = red(1)
         if (.not. (pq > 0.0_dp)) then
            stat = FOLD_NUMERICAL
            write (errmsg, '(a,i0,a,es10.3)') "stokes_rigid_solve: CG breakdown at iteration ", it, &
               ", <p, S p> = ", pq
            s%iterations = it
            if (s%stencil) call to_staggered(s, s%x)
            return
         end if
         alpha = rz/pq
         s%lam(:, 1:s%nsol) = s%lam(:, 1:s%nsol) + alpha*s%dir(:, 1:s%nsol)
         s%res(:, 1:s%nsol) = s%res(:, 1:s%nsol) - alpha*s%sdir(:, 1:s%nsol)
         s%x = s%x + alpha*s%q
         ! z = W r into sdir (free until the next apply_schur)
         call precondition(s, s%res, s%sdir)
         red = [dot_list(s, s%res, s%res), dot_list(s, s%res, s%sdir)]
         call s%fft%sum_all(red)
         rr = red(1)
         beta = red(2)/rz
         rz = red(2)
         s%residual = sqrt(max(rr, 0.0_dp)/bb)
         s%history(it) = s%residual
         s%dir(:, 1:s%nsol) = s%sdir(:, 1:s%nsol) + beta*s%dir(:, 1:s%nsol)
      end do
      s%iterations = it
      s%have_guess = .true.
      if (s%stencil) call to_staggered(s, s%x)

      ! the solid voxels' multiplier as fields (next guess) and its mean, the particles' stress
      s%lam_field = 0.0_dp
      do v = 1, s%nsol
         if (s%comp(v) == 0.0_dp) s%lam_field(:, s%sol(1, v), s%sol(2, v), s%sol(3, v)) = s%lam(:, v)
      end do
      call multiplier_mean(s)
      call solve_verdict(s%set, "stokes_rigid_solve", "CG", it, s%residual, stat, errmsg)
   end subroutine stokes_rigid_solve

   ! ------------------------------------------------------------------ internals

   !> The local voxels the particles touch (chi > 0), listed once per solve with their
   !> compliance: 0 where chi >= FOLD_RIGID_COVERAGE (rigid), else 1 / (2 (eta - eta_f))
   !> = (1 - chi) / (2 eta_f chi), the harmonic mixing's viscosity eta_f / (1 - chi) at
   !> kappa -> infinity (at most 2 eta_f below coverage 1/2: a well-conditioned diagonal).
   subroutine solid_list(s, chi)
      type(stokes_rigid_t), intent(inout) :: s
      real(dp), intent(in) :: chi(:, :, :)
      integer(ip) :: i, j, k, n, cap
      real(dp) :: c
      n = int(count(chi > 0.0_dp), ip)
      cap = size(s%sol, 2)
      if (cap < n) then
         deallocate (s%sol, s%comp, s%lam, s%res, s%dir, s%sdir)
         cap = n + n/4
         allocate (s%sol(3, cap), s%comp(cap), s%lam(s%ncg, cap), s%res(s%ncg, cap), s%dir(s%ncg, cap), &
                   s%sdir(s%ncg, cap))
      end if
      s%lam = 0.0_dp
      s%res = 0.0_dp
      s%dir = 0.0_dp
      s%sdir = 0.0_dp
      n = 0
      do k = 1, size(chi, 3)
         do j = 1, size(chi, 2)
            do i = 1, size(chi, 1)
               c = chi(i, j, k)
               if (c > 0.0_dp) then
                  n = n + 1
                  s%sol(:, n) = [i, j, k]
                  s%comp(n) = 0.0_dp
                  if (c < FOLD_RIGID_COVERAGE) s%comp(n) = (1.0_dp - c)/(2.0_dp*s%set%eta_f*c)
               end if
            end do
         end do
      end do
      s%nsol = n
   end subroutine solid_list

   !> z = W r with W = g0 / (g0 + C) per listed voxel, g0 = (dim - 1) / (2 eta_f ncg) the
   !> mean diagonal of Gamma (on every kept mode Gamma is 1/(2 eta_f) times a projector of
   !> rank dim - 1 among the ncg deviatoric components): 1 on the solid voxels.
   subroutine precondition(s, r, z)
      type(stokes_rigid_t), intent(in) :: s
      real(dp), intent(in) :: r(:, :)
      real(dp), intent(inout) :: z(:, :)
      real(dp) :: g0
      integer(ip) :: v
      g0 = real(s%dim - 1, dp)/(2.0_dp*s%set%eta_f*real(s%ncg, dp))
      do v = 1, s%nsol
         z(:, v) = r(:, v)*(g0/(g0 + s%comp(v)))
      end do
   end subroutine precondition

   !> The ncg independent components of a traceless symmetric tensor (3-D: 11, 22, 12,
   !> 13, 23; 2-D: 11, 12).
   function reduced(s, t) result(v)
      type(stokes_rigid_t), intent(in) :: s
      real(dp), intent(in) :: t(3, 3)
      real(dp) :: v(5)
      v = 0.0_dp
      if (s%dim == 3) then
         v = [t(1, 1), t(2, 2), t(1, 2), t(1, 3), t(2, 3)]
      else
         v(1:2) = [t(1, 1), t(1, 2)]
      end if
   end function reduced

   !> Frobenius product of two traceless symmetric tensors in reduced components.
   pure function frob(s, a, b) result(v)
      type(stokes_rigid_t), intent(in) :: s
      real(dp), intent(in) :: a(:), b(:)
      real(dp) :: v
      if (s%dim == 3) then
         v = a(1)*b(1) + a(2)*b(2) + (a(1) + a(2))*(b(1) + b(2)) + 2.0_dp*(a(3)*b(3) + a(4)*b(4) + a(5)*b(5))
      else
         v = 2.0_dp*(a(1)*b(1) + a(2)*b(2))
      end if
   end function frob

   !> Local sum of the Frobenius products over the solid voxels.
   function dot_list(s, a, b) result(v)
      type(stokes_rigid_t), intent(in) :: s
      real(dp), intent(in) :: a(:, :), b(:, :)
      real(dp) :: v
      integer(ip) :: n
      v = 0.0_dp
      do n = 1, s%nsol
         v = v + frob(s, a(:, n), b(:, n))
      end do
   end function dot_list

   !> sdir = (Gamma + C) dir on the listed voxels, and q = the Fourier velocity
   !> -A^-1 P B^H dir of the direction (unnormalised transforms; staggered as s%x in the
   !> spectral form, unstaggered in the stencil form).
   subroutine apply_schur(s)
      type(stokes_rigid_t), intent(inout) :: s
      if (s%stencil) then
         call apply_schur_stencil(s)
      else
         call apply_schur_spectral(s)
      end if
   end subroutine apply_schur

   !> apply_schur by transforms of the ncg independent stress and strain components.
   subroutine apply_schur_spectral(s)
      type(stokes_rigid_t), intent(inout) :: s
      integer(ip) :: c, v, i, j, k, fc, ncg
      real(dp) :: kv(3), scale, ik2
      complex(dp) :: t(3, 3), f(3), u(3)
      ncg = s%ncg
      ! the direction's stress on the solid voxels, one field per independent component
      do c = 1, ncg
         fc = s%cg_comp(c)
         s%work(fc)%r = 0.0_dp
         do v = 1, s%nsol
            s%work(fc)%r(s%sol(1, v), s%sol(2, v), s%sol(3, v)) = s%dir(c, v)
         end do
         call s%fft%r2c(s%work(fc))
      end do
      ! force kv . tau, projected, through the Green operator; its strain per mode
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            do i = 1, s%fft%nxh
               ik2 = s%ik2(i, j, k)
               if (ik2 == 0.0_dp) then
                  s%q(i, j, k, :) = 0.0_dp
                  do c = 1, ncg
                     s%work(s%cg_comp(c))%c(i, j, k) = 0.0_dp
                  end do
                  cycle
               end if
               kv = 0.0_dp
               kv(1:s%dim) = s%kv(:, i, j, k)
               t = 0.0_dp
               if (s%dim == 3) then
                  t(1, 1) = s%work(1)%c(i, j, k)
                  t(2, 2) = s%work(2)%c(i, j, k)
                  t(3, 3) = -(t(1, 1) + t(2, 2))
                  t(1, 2) = s%work(4)%c(i, j, k)
                  t(1, 3) = s%work(5)%c(i, j, k)
                  t(2, 3) = s%work(6)%c(i, j, k)
               else
                  t(1, 1) = s%work(1)%c(i, j, k)
                  t(2, 2) = -t(1, 1)
                  t(1, 2) = s%work(3)%c(i, j, k)
               end if
               t(2, 1) = t(1, 2)
               t(3, 1) = t(1, 3)
               t(3, 2) = t(2, 3)
               f = matmul(t, cmplx(kv, 0.0_dp, dp))
               f = f - kv*sum(kv*f)*ik2
               u = -f*(ik2/s%set%eta_f)
               s%q(i, j, k, :) = u(1:s%dim)
               if (s%dim == 3) then
                  s%work(1)%c(i, j, k) = kv(1)*u(1)
                  s%work(2)%c(i, j, k) = kv(2)*u(2)
                  s%work(4)%c(i, j, k) = 0.5_dp*(kv(1)*u(2) + kv(2)*u(1))
                  s%work(5)%c(i, j, k) = 0.5_dp*(kv(1)*u(3) + kv(3)*u(1))
                  s%work(6)%c(i, j, k) = 0.5_dp*(kv(2)*u(3) + kv(3)*u(2))
               else
                  s%work(1)%c(i, j, k) = kv(1)*u(1)
                  s%work(3)%c(i, j, k) = 0.5_dp*(kv(1)*u(2) + kv(2)*u(1))
               end if
            end do
         end do
      end do
      ! strain of the direction's velocity at the solid voxels: S dir = -chi_s eps
      scale = 1.0_dp/real(grid_total(s%grid), dp)
      do c = 1, ncg
         fc = s%cg_comp(c)
         call s%fft%c2r(s%work(fc))
         do v = 1, s%nsol
            s%sdir(c, v) = -scale*s%work(fc)%r(s%sol(1, v), s%sol(2, v), s%sol(3, v)) + s%comp(v)*s%dir(c, v)
         end do
      end do
   end subroutine apply_schur_spectral

   !> apply_schur in the stencil form (3-D rotated differences, fold_cg_kernels.f90.in
   !> header): the corner force D^T tau scattered in real space from the listed voxels,
   !> 3 r2c, the Green operator per mode on the unstaggered corner coefficients (P and
   !> 1/|kv|^2 are real per mode, so they commute with the staggering phase), 3 c2r, the
   !> strain D u gathered at the listed voxels: 6 transforms instead of 10. The corner
   !> plane after the slab is exchanged with the next rank both ways (fold_stokes_fft's
   !> hfirst/uhi and fover/frecv).
   subroutine apply_schur_stencil(s)
      type(stokes_rigid_t), intent(inout) :: s
      integer(ip) :: c, v, i, j, k, i1, j1, nx, ny, nz
      real(dp) :: t(3, 3), tt(3, 3), w(2, 2, 2), d(3, 3), gg(3, 3), kv(3), ik2, scale, ef
      complex(dp) :: f(3)
      nx = s%grid%n(1)
      ny = s%grid%nl(2)
      nz = s%grid%nl(3)
      do c = 1, 3
         s%work(c)%r = 0.0_dp
      end do
      s%fover = 0.0_dp
      do v = 1, s%nsol
         call voxel_of(v)
         t = full(s%dir(:, v))
         ! tt(c, l) = sum_b tau(c, b) aith(b, l); corner o gets sum_l s_l(o) tt(c, l)
         tt = matmul(t, s%aith)
         do c = 1, 3
            w(1, :, :) = -tt(c, 1)
            w(2, :, :) = tt(c, 1)
            w(:, 1, :) = w(:, 1, :) - tt(c, 2)
            w(:, 2, :) = w(:, 2, :) + tt(c, 2)
            w(:, :, 1) = w(:, :, 1) - tt(c, 3)
            w(:, :, 2) = w(:, :, 2) + tt(c, 3)
            associate (fc => s%work(c)%r)
               fc(i, j, k) = fc(i, j, k) + w(1, 1, 1)
               fc(i1, j, k) = fc(i1, j, k) + w(2, 1, 1)
               fc(i, j1, k) = fc(i, j1, k) + w(1, 2, 1)
               fc(i1, j1, k) = fc(i1, j1, k) + w(2, 2, 1)
               if (k < nz) then
                  fc(i, j, k + 1) = fc(i, j, k + 1) + w(1, 1, 2)
                  fc(i1, j, k + 1) = fc(i1, j, k + 1) + w(2, 1, 2)
                  fc(i, j1, k + 1) = fc(i, j1, k + 1) + w(1, 2, 2)
                  fc(i1, j1, k + 1) = fc(i1, j1, k + 1) + w(2, 2, 2)
               else
                  s%fover(i, j, c) = s%fover(i, j, c) + w(1, 1, 2)
                  s%fover(i1, j, c) = s%fover(i1, j, c) + w(2, 1, 2)
                  s%fover(i, j1, c) = s%fover(i, j1, c) + w(1, 2, 2)
                  s%fover(i1, j1, c) = s%fover(i1, j1, c) + w(2, 2, 2)
               end if
            end associate
         end do
      end do
      ! the force on the corner plane after the slab belongs to the next rank's first
      call s%fft%z_halo(size(s%fover, kind=i8), s%fover, s%fover, s%frecv, s%hscr)
      do c = 1, 3
         s%work(c)%r(1:nx, :, 1) = s%work(c)%r(1:nx, :, 1) + s%frecv(1:nx, :, c)
         call s%fft%r2c(s%work(c))
      end do
      ef = s%set%eta_f
      do k = 1, s%fft%nsl(3)
         do j = 1, s%fft%nsl(2)
            do i = 1, s%fft%nxh
               ik2 = s%ik2(i, j, k)
               if (ik2 == 0.0_dp) then
                  f = 0.0_dp
               else
                  kv = s%kv(:, i, j, k)
                  f = [s%work(1)%c(i, j, k), s%work(2)%c(i, j, k), s%work(3)%c(i, j, k)]
                  f = -(f - kv*sum(kv*f)*ik2)*(ik2/ef)
               end if
               s%q(i, j, k, :) = f
               s%work(1)%c(i, j, k) = f(1)
               s%work(2)%c(i, j, k) = f(2)
               s%work(3)%c(i, j, k) = f(3)
            end do
         end do
      end do
      do c = 1, 3
         call s%fft%c2r(s%work(c))
         s%hfirst(:, :, c) = s%work(c)%r(:, :, 1)
      end do
      ! the next rank's first corner plane: the upper corners of this slab's last plane
      call s%fft%z_halo(size(s%hfirst, kind=i8), s%hfirst, s%hfirst, s%hscr, s%uhi)
      scale = 1.0_dp/real(grid_total(s%grid), dp)
      do v = 1, s%nsol
         call voxel_of(v)
         do c = 1, 3
            call lattice_differences(s%work(c)%r, s%uhi(:, :, c), d(c, :))
         end do
         ! physical gradient gg(c, b) = sum_l aith(b, l) d(c, l)
         gg = matmul(d, transpose(s%aith))
         t = 0.5_dp*(gg + transpose(gg))
         s%sdir(:, v) = -scale*reduced(s, t) + s%comp(v)*s%dir(:, v)
      end do
   contains

      !> (i, j, k): the voxel of listed point v; i1, j1 its upper neighbours across the
      !> periodic x and y faces.
      subroutine voxel_of(v)
         integer(ip), intent(in) :: v
         i = s%sol(1, v)
         j = s%sol(2, v)
         k = s%sol(3, v)
         i1 = merge(1_ip, i + 1, i == nx)
         j1 = merge(1_ip, j + 1, j == ny)
      end subroutine voxel_of

      !> The unscaled lattice differences (x, y, z) of one component at the centre (i, j, k)
      !> from its eight corners (the upper z-plane from the next rank on the slab's last).
      subroutine lattice_differences(uc, up, dd)
         real(dp), intent(in) :: uc(:, :, :), up(:, :)
         real(dp), intent(out) :: dd(3)
         real(dp) :: v000, v100, v010, v110, v001, v101, v011, v111
         v000 = uc(i, j, k)
         v100 = uc(i1, j, k)
         v010 = uc(i, j1, k)
         v110 = uc(i1, j1, k)
         if (k < nz) then
            v001 = uc(i, j, k + 1)
            v101 = uc(i1, j, k + 1)
            v011 = uc(i, j1, k + 1)
            v111 = uc(i1, j1, k + 1)
         else
            v001 = up(i, j)
            v101 = up(i1, j)
            v011 = up(i, j1)
            v111 = up(i1, j1)
         end if
         dd(1) = ((v100 - v000) + (v110 - v010)) + ((v101 - v001) + (v111 - v011))
         dd(2) = ((v010 + v110) - (v000 + v100)) + ((v011 + v111) - (v001 + v101))
         dd(3) = ((v001 + v101) - (v000 + v100)) + ((v011 + v111) - (v010 + v110))
      end subroutine lattice_differences

   end subroutine apply_schur_stencil

   !> u <- i phase u, per mode (the stencil form's unstaggered coefficients to the
   !> staggered ones of s%x; fold_stokes_fft's tables ph1, ph23).
   subroutine to_staggered(s, u)
      type(stokes_rigid_t), intent(in) :: s
      complex(dp), intent(inout) :: u(:, :, :, :)
      integer(ip) :: i, j, k, c
      do c = 1, s%dim
         do k = 1, s%fft%nsl(3)
            do j = 1, s%fft%nsl(2)
               do i = 1, s%fft%nxh
                  u(i, j, k, c) = s%ph1(i)*s%ph23(j + (k - 1)*s%fft%nsl(2))*u(i, j, k, c)
               end do
            end do
         end do
      end do
   end subroutine to_staggered

   !> The polarisation's mean <tau> over the cell into s%multiplier_stress [Pa] and its
   !> dissipation <tau : eps> into s%multiplier_dissipation [Pa/s], with the strain on the
   !> listed voxels eps = E - Gamma tau = r + C tau (r the CG residual); summed over ranks.
   subroutine multiplier_mean(s)
      type(stokes_rigid_t), intent(inout) :: s
      real(dp) :: red(6), m(3, 3)
      integer(ip) :: v
      red = 0.0_dp
      do v = 1, s%nsol
         red(1:s%ncg) = red(1:s%ncg) + s%lam(:, v)
         red(6) = red(6) + frob(s, s%lam(:, v), s%res(:, v) + s%comp(v)*s%lam(:, v))
      end do
      call s%fft%sum_all(red)
      red = red/real(grid_total(s%grid), dp)
      s%multiplier_dissipation = red(6)
      if (s%dim == 3) then
         m = full(red(1:5))
      else
         m = 0.0_dp
         m(1, 1) = red(1)
         m(2, 2) = -red(1)
         m(1, 2) = red(2)
         m(2, 1) = red(2)
      end if
      s%multiplier_stress = m
   end subroutine multiplier_mean

   !> The full symmetric tensor of reduced components (3-D): r = (m11, m22, m12, m13, m23).
   pure function full(r) result(m)
      real(dp), intent(in) :: r(:)
      real(dp) :: m(3, 3)
      m(1, 1) = r(1)
      m(2, 2) = r(2)
      m(3, 3) = -(r(1) + r(2))
      m(1, 2) = r(3)
      m(2, 1) = r(3)
      m(1, 3) = r(4)
      m(3, 1) = r(4)
      m(2, 3) = r(5)
      m(3, 2) = r(5)
   end function full

end module fold_stokes_rigid
