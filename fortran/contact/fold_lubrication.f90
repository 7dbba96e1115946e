!> Lubrication between spheres as a velocity correction (docs/physics.md#lubrication-between-spheres).
!>
!> Pair force (the seed's formula, generalised to radii R_i, R_j by the reduced radius
!> R* = R_i R_j/(R_i + R_j); equal spheres: 6 pi R*^2 = (3/2) pi R^2, the seed's prefactor;
!> Jeffrey & Onishi 1984, J. Fluid Mech. 139:261, leading term of X^A_11):
!>     F_ij = -c_ij ((u_i - u_j).n_ij) n_ij,   n_ij = O_jO_i/|O_jO_i| (minimum image),
!>     c_ij = 6 pi eta R*^2 (1/max(h, gap_min) - 1/h_c)   for h = |O_jO_i| - R_i - R_j < h_c,
!>     c_ij = 0                                             otherwise.
!> The force acts on sphere i; sphere j gets -F_ij. u_j is the velocity of the image
!> of j next to i: the velocity of j plus the mean-flow difference between the two
!> images (G a for a lattice vector a, fold_cell's frame rule), so pairs across a
!> sheared (Lees-Edwards) face see their true relative velocity.
!>
!> Why 1/h - 1/h_c and not the seed's bare 1/h. The flow velocities v0 come from the
!> fictitious-domain solve, which already carries the squeeze flow of every gap it
!> resolves; the correction adds only what the grid misses (the singular part below
!> h_c), the subtraction used for lattice-Boltzmann suspensions (Nguyen & Ladd 2002,
!> Phys. Rev. E 66:046708). It also makes c_ij continuous (zero) at h = h_c, so a
!> pair drifting across the threshold gets no velocity jump. For h << h_c the two forms
!> agree to O(h/h_c). h_c = huge gives the seed's form exactly.
!>
!> Threshold h_c = 2 voxel widths (lubrication_threshold). The partial-volume chi
!> smears each surface over one voxel, so a gap has a voxel of pure fluid across it
!> only when it is wider than about two voxels: a narrower gap is a mix of fluid and
!> particle viscosity on the grid, whose squeeze resistance no longer grows like 1/h.
!>
!> Floor gap_min = max(alpha, 1e-3 h_c) (lubrication_gap_floor). The collision strategy
!> ends every step with all gaps >= alpha (fold_contacts), so with alpha > 0 the floor
!> only acts after a capped contact pass (on_contact_cap = continue); inside the
!> security zone the seed treats the pair as a collision ("no fluid between the
!> spheres"), and the coefficient stays at its value at alpha. The 1e-3 h_c part only
!> matters for alpha = 0: it bounds c_ij by 1000 times its value at h_c, and with it
!> the condition number of the system below, while a pair that close already keeps
!> only ~2 gap/R* of its approach speed (the correction has saturated).
!>
!> Mobility and system. Each sphere moves by the force through the mobility of an
!> isolated sphere, delta v_i = F_i/(6 pi eta R_i), F_i = sum_j F_ij evaluated at the
!> corrected velocities u = v0 + delta v. All pairs at once:
!>     (M + L) delta v = b,   M = diag(6 pi eta R_i) (x identity),
!>     (L y)_i = sum_j c_ij ((y_i - y_j).n_ij) n_ij,   b_i = -sum_j c_ij w0_ij n_ij,
!> with w0_ij = (v0_i - v0_j - G a).n_ij the flow's normal approach rate of the pair (for
!> pairs inside the cell b = -L v0). L is a sum of c (e_i - e_j)(e_i - e_j)^T (x) n n^T,
!> symmetric positive semidefinite, so M + L is SPD; eta cancels (delta v does not
!> depend on the viscosity, only the forces do). Solved by conjugate gradients with
!> the diagonal as preconditioner to the round-off level
!>     ||b - (M + L) delta v||_2 <= 64 eps (a ||delta v||_2 + ||b||_2),
!>     a = max_i (6 pi eta R_i + 2 sqrt(dim) sum_j c_ij) >= ||M + L||_2,
!> the size of the rounding error of one product (M + L) y (each row sums one term per
!> neighbour and per component: 64 covers ~50 neighbours). The true residual is
!> recomputed at the end and CG restarted from it until it meets the bound, so the
!> recursive residual's drift cannot end the solve early. Two spheres approaching along
!> their line of centres: delta v_i = -c w0/(M + 2c) n for equal radii, the closed
!> form tests/ and docs use. Only translations change: the force is central, so it
!> exerts no torque on a sphere. Only sphere-sphere pairs (no sphere-wall term, no
!> fibre or spheroid); only dim = 3 (a 2-D disk has no isolated Stokes mobility).
!>
!> Measured (studies/lubrication/pair_approach.py, docs/physics.md#lubrication-between-spheres):
!> with this mobility the correction slows two near spheres 2-8 times below the approach
!> rate the refined Stokes flow converges to; the flow already resolves much of the pair
!> resistance below h_c, which the isolated-sphere mobility ignores. Qualitative only.
!>
!> Pairs come from the cell lists of fold_cell_list (neighbour_pairs, range
!> 2 R_max + h_c), minimum images from fold_cell (walls, Lees-Edwards and deforming
!> lattices as for the contacts); every periodic edge must exceed twice that range.
module fold_lubrication
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NOT_CONVERGED
   use fold_cell, only: cell_t, cell_min_image, cell_mean_velocity
   use fold_cell_list, only: neighbour_pairs
   implicit none
   private

   !> What one correction did.
   type, public :: lubrication_stats_t
      !> Sphere pairs closer than h_c (c_ij > 0)
      integer(ip) :: pairs = 0
      !> Conjugate-gradient iterations (all restarts)
      integer(ip) :: iterations = 0
      !> ||b - (M + L) delta v||_2 reached, and the round-off bound it had to meet [N]
      real(dp) :: residual = 0.0_dp, residual_bound = 0.0_dp
      !> Largest |delta v_i| [m/s]
      real(dp) :: max_correction = 0.0_dp
      !> Smallest surface gap of the lubricated pairs (huge when none) [m]
      real(dp) :: min_gap = huge(1.0_dp)
   end type lubrication_stats_t

   !> Pairs of the system: sphere indices, unit normal from b to a, coefficient, flow approach rate.
   type, public :: lubrication_pairs_t
      integer(ip) :: n = 0
      integer(ip), allocatable :: ab(:, :)
      real(dp), allocatable :: nrm(:, :)
      !> c_ab [N s/m]
      real(dp), allocatable :: c(:)
      !> w0_ab = (v0_a - v0_b - G a).n_ab [m/s]
      real(dp), allocatable :: w0(:)
      !> Surface gap [m]
      real(dp), allocatable :: gap(:)
   end type lubrication_pairs_t

   !> h_c in voxel widths (module header)
   real(dp), parameter, public :: LUB_THRESHOLD_VOXELS = 2.0_dp
   !> gap_min >= this fraction of h_c (module header)
   real(dp), parameter, public :: LUB_FLOOR_OF_THRESHOLD = 1.0e-3_dp
   !> Round-off factor of the residual bound (module header)
   real(dp), parameter :: RESID_FACTOR = 64.0_dp
   !> Restarts of CG from the true residual
   integer, parameter :: MAX_RESTARTS = 8
   real(dp), parameter :: PI = acos(-1.0_dp)

   public :: lubrication_threshold, lubrication_gap_floor, lubrication_coefficient, lubrication_force
   public :: lubrication_correct, lubrication_apply

contains

   !> Threshold gap h_c below which the grid does not resolve the squeeze flow:
   !> LUB_THRESHOLD_VOXELS voxel widths [m].
   elemental function lubrication_threshold(voxel) result(h_c)
      !> Voxel width of the Stokes grid [m]
      real(dp), intent(in) :: voxel
      real(dp) :: h_c
      h_c = LUB_THRESHOLD_VOXELS*voxel
   end function lubrication_threshold

   !> Smallest gap of the coefficient, max(alpha, LUB_FLOOR_OF_THRESHOLD h_c) [m].
   elemental function lubrication_gap_floor(alpha, h_c) result(gap_min)
      !> Security zone [m]
      real(dp), intent(in) :: alpha
      !> Threshold gap [m]
      real(dp), intent(in) :: h_c
      real(dp) :: gap_min
      gap_min = max(alpha, LUB_FLOOR_OF_THRESHOLD*h_c)
   end function lubrication_gap_floor

   !> Pair coefficient c = 6 pi eta R*^2 max(0, 1/max(gap, gap_min) - 1/h_c), R* = R_i R_j/(R_i + R_j)
   !> (zero from gap >= h_c on; h_c = huge: the seed's 1/gap) [N s/m]. The one statement
   !> of the lubrication formula in the code.
   elemental function lubrication_coefficient(r_i, r_j, eta, gap, gap_min, h_c) result(c)
      !> Radii [m]
      real(dp), intent(in) :: r_i, r_j
      !> Fluid viscosity [Pa s]
      real(dp), intent(in) :: eta
      !> Surface gap |O_jO_i| - R_i - R_j [m]
      real(dp), intent(in) :: gap
      !> Floor of the gap (> 0) and threshold gap [m]
      real(dp), intent(in) :: gap_min, h_c
      real(dp) :: c, rs
      c = 0.0_dp
      if (.not. (gap < h_c)) return
      rs = r_i*r_j/(r_i + r_j)
      c = 6.0_dp*PI*eta*rs**2*max(0.0_dp, 1.0_dp/max(gap, gap_min) - 1.0_dp/h_c)
   end function lubrication_coefficient

   !> Lubrication force on sphere i from sphere j, F_ij = -c_ij ((u_i - u_j).n_ij) n_ij [N].
   pure function lubrication_force(r_i, r_j, eta, dx, du, gap_min, h_c) result(f)
      !> Radii [m]
      real(dp), intent(in) :: r_i, r_j
      !> Fluid viscosity [Pa s]
      real(dp), intent(in) :: eta
      !> O_i - O_j (minimum image) [m]
      real(dp), intent(in) :: dx(:)
      !> u_i - u_j (of the image next to i) [m/s]
      real(dp), intent(in) :: du(:)
      !> Floor of the gap and threshold gap [m]
      real(dp), intent(in) :: gap_min, h_c
      real(dp) :: f(size(dx))
      real(dp) :: dist, n(size(dx))
      dist = norm2(dx)
      n = dx/dist
      f = -lubrication_coefficient(r_i, r_j, eta, dist - r_i - r_j, gap_min, h_c)*dot_product(du, n)*n
   end function lubrication_force

   !> y_out = (M + L) y for the pairs (mob(k) = 6 pi eta R_k for spheres; y, y_out (dim, n)).
   pure subroutine lubrication_apply(pairs, mob, y, y_out)
      type(lubrication_pairs_t), intent(in) :: pairs
      real(dp), intent(in) :: mob(:), y(:, :)
      real(dp), intent(out) :: y_out(:, :)
      integer(ip) :: k, a, b
      real(dp) :: s
      do k = 1, int(size(y, 2), ip)
         y_out(:, k) = mob(k)*y(:, k)
      end do
      do k = 1, pairs%n
         a = pairs%ab(1, k)
         b = pairs%ab(2, k)
         s = pairs%c(k)*dot_product(y(:, a) - y(:, b), pairs%nrm(:, k))
         y_out(:, a) = y_out(:, a) + s*pairs%nrm(:, k)
         y_out(:, b) = y_out(:, b) - s*pairs%nrm(:, k)
      end do
   end subroutine lubrication_apply

   !> Lubrication corrections dv(dim, n) of the flow velocities v0 (module header): zero
   !> for non-spheres and spheres without a pair closer than h_c. FOLD_NOT_CONVERGED when
   !> the residual bound is not met (dv then holds the last iterate).
   subroutine lubrication_correct(cell, x, radius, sphere, v0, eta, h_c, gap_min, dv, stats, stat, errmsg)
      type(cell_t), intent(in) :: cell
      !> Centres x(dim, n) [m], radii [m], which particles are spheres
      real(dp), intent(in) :: x(:, :), radius(:)
      logical, intent(in) :: sphere(:)
      !> Flow velocities v0(dim, n) [m/s]
      real(dp), intent(in) :: v0(:, :)
      !> Fluid viscosity [Pa s]
      real(dp), intent(in) :: eta
      !> Threshold gap (> gap_min) and floor of the gap (> 0) [m]
      real(dp), intent(in) :: h_c, gap_min
      real(dp), intent(out) :: dv(:, :)
      type(lubrication_stats_t), intent(out) :: stats
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(lubrication_pairs_t) :: pairs
      real(dp), allocatable :: mob(:), diag(:, :), rhs(:, :), r(:, :), z(:, :), p(:, :), q(:, :), csum(:)
      integer(ip) :: n, dim, k, a, b, max_it
      integer :: restart
      real(dp) :: anorm, bnorm, tau, rz, rz_new, alpha_cg, rnorm
      logical :: met

      stat = FOLD_INPUT_ERROR
      errmsg = ""
      dv = 0.0_dp
      dim = int(size(x, 1), ip)
      n = int(size(x, 2), ip)
      if (dim /= 3 .or. cell%dim /= 3) then
         write (errmsg, '(a,i0)') "lubrication: defined for spheres in 3-D (a 2-D disk has no isolated "// &
            "Stokes mobility), got dim ", dim
         return
      end if
      if (size(radius) /= n .or. size(sphere) /= n .or. any(shape(v0) /= [dim, n]) .or. &
          any(shape(dv) /= [dim, n])) then
         errmsg = "lubrication: x, radius, sphere, v0 and dv describe different numbers of particles"
         return
      end if
      if (.not. (eta > 0.0_dp .and. gap_min > 0.0_dp .and. h_c > gap_min)) then
         write (errmsg, '(a,3es11.3)') "lubrication: need eta > 0 and 0 < gap_min < h_c, got eta, gap_min, h_c = ", &
            eta, gap_min, h_c
         return
      end if
      if (any(sphere .and. .not. (radius > 0.0_dp))) then
         errmsg = "lubrication: every sphere radius must be > 0"
         return
      end if
      call find_pairs(pairs, stat, errmsg)
      if (stat /= FOLD_OK) return
      stats%pairs = pairs%n
      if (pairs%n == 0) return
      stats%min_gap = minval(pairs%gap(1:pairs%n))

      ! M, the diagonal preconditioner, b, and the norm bound a
      allocate (mob(n), diag(dim, n), rhs(dim, n), csum(n))
      mob = merge(6.0_dp*PI*eta*radius, 1.0_dp, sphere)
      csum = 0.0_dp
      rhs = 0.0_dp
      do k = 1, n
         diag(:, k) = mob(k)
      end do
      do k = 1, pairs%n
         a = pairs%ab(1, k)
         b = pairs%ab(2, k)
         diag(:, a) = diag(:, a) + pairs%c(k)*pairs%nrm(:, k)**2
         diag(:, b) = diag(:, b) + pairs%c(k)*pairs%nrm(:, k)**2
         rhs(:, a) = rhs(:, a) - pairs%c(k)*pairs%w0(k)*pairs%nrm(:, k)
         rhs(:, b) = rhs(:, b) + pairs%c(k)*pairs%w0(k)*pairs%nrm(:, k)
         csum(a) = csum(a) + pairs%c(k)
         csum(b) = csum(b) + pairs%c(k)
      end do
      anorm = maxval(mob + 2.0_dp*sqrt(real(dim, dp))*csum)
      bnorm = norm2(rhs)

      ! preconditioned CG, restarted from the true residual until it meets the bound
      allocate (r(dim, n), z(dim, n), p(dim, n), q(dim, n))
      max_it = 10*dim*n + 100
      met = .false.
      do restart = 0, MAX_RESTARTS
         call lubrication_apply(pairs, mob, dv, q)
         r = rhs - q
         rnorm = norm2(r)
         tau = RESID_FACTOR*epsilon(1.0_dp)*(anorm*norm2(dv) + bnorm)
         stats%residual = rnorm
         stats%residual_bound = tau
         if (rnorm <= tau) then
            met = .true.
            exit
         end if
         if (stats%iterations >= max_it) exit
         z = r/diag
         p = z
         rz = sum(r*z)
         do while (stats%iterations < max_it)
            call lubrication_apply(pairs, mob, p, q)
            alpha_cg = rz/sum(p*q)
            dv = dv + alpha_cg*p
            r = r - alpha_cg*q
            stats%iterations = stats%iterations + 1
            if (norm2(r) <= RESID_FACTOR*epsilon(1.0_dp)*(anorm*norm2(dv) + bnorm)) exit
            z = r/diag
            rz_new = sum(r*z)
            p = z + (rz_new/rz)*p
            rz = rz_new
         end do
      end do
      ! the non-spheres are outside every pair: their rows read mob*dv = 0
      where (spread(.not. sphere, 1, dim)) dv = 0.0_dp
      stats%max_correction = maxval(norm2(dv, dim=1))
      stat = FOLD_OK
      if (.not. met) then
         stat = FOLD_NOT_CONVERGED
         write (errmsg, '(a,i0,a,i0,a,es10.3,a,es10.3,a)') "lubrication: the correction of ", pairs%n, &
            " pairs did not reach the round-off residual after ", stats%iterations, " CG iterations (", &
            stats%residual, " N, bound ", stats%residual_bound, " N)"
      end if

   contains

      !> The lubricated pairs of the spheres (sphere(k) true) of lubrication_correct's
      !> arguments, with their normal, coefficient and flow approach rate w0, found with
      !> the cell lists.
      subroutine find_pairs(pairs, stat, errmsg)
         type(lubrication_pairs_t), intent(out) :: pairs
         integer, intent(out) :: stat
         character(len=msg_len), intent(out) :: errmsg
         integer(ip), allocatable :: idx(:), cand(:, :)
         real(dp), allocatable :: xs(:, :)
         integer(ip) :: m, np, k, a, b, dim
         real(dp) :: dx(size(x, 1)), dist, gap, c, rc

         dim = int(size(x, 1), ip)
         allocate (pairs%ab(2, 0), pairs%nrm(dim, 0), pairs%c(0), pairs%w0(0), pairs%gap(0))
         stat = FOLD_OK
         errmsg = ""
         idx = pack([(k, k=1, int(size(x, 2), ip))], sphere)
         m = int(size(idx), ip)
         if (m < 2) return
         xs = x(:, idx)
         rc = 2.0_dp*maxval(radius(idx)) + h_c
         allocate (cand(2, 8*m))
         do
            call neighbour_pairs(cell, xs, rc, .true., cand, np, stat, errmsg)
            if (stat == FOLD_OK) exit
            if (np <= size(cand, 2)) then
               errmsg = "lubrication: "//trim(errmsg)
               return
            end if
            deallocate (cand)
            allocate (cand(2, np))
         end do
         deallocate (pairs%ab, pairs%nrm, pairs%c, pairs%w0, pairs%gap)
         allocate (pairs%ab(2, np), pairs%nrm(dim, np), pairs%c(np), pairs%w0(np), pairs%gap(np))
         do k = 1, np
            a = idx(cand(1, k))
            b = idx(cand(2, k))
            dx = x(:, a) - x(:, b)
            call cell_min_image(cell, dx)
            dist = norm2(dx)
            gap = dist - radius(a) - radius(b)
            c = lubrication_coefficient(radius(a), radius(b), eta, gap, gap_min, h_c)
            if (.not. (c > 0.0_dp)) cycle
            pairs%n = pairs%n + 1
            pairs%ab(:, pairs%n) = [a, b]
            pairs%nrm(:, pairs%n) = dx/dist
            pairs%c(pairs%n) = c
            pairs%gap(pairs%n) = gap
            ! the image of b next to a sits at x_a - dx and moves with v0_b plus the
            ! mean-flow difference between that image and b itself
            pairs%w0(pairs%n) = dot_product(v0(:, a) - v0(:, b) - &
                                            (cell_mean_velocity(cell, x(:, a) - dx) - cell_mean_velocity(cell, x(:, b))), &
                                            dx/dist)
         end do
      end subroutine find_pairs
   end subroutine lubrication_correct

end module fold_lubrication
