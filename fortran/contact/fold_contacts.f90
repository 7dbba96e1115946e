!> The seed's collision strategy (Laure, Megally & Coupez; physics.md section 3).
!>
!> Gaps are evaluated at the PREDICTED configuration at t + dt (x + v dt, p turned
!> exactly by omega dt, cell offset advanced by dt), exactly as rigid_update will move
!> the particles. For every particle i the worst pair D_i = min_j d_ij,
!>     d_ij = dist_ij - alpha,  dist_ij = surface distance of the two capsules,
!> is found; if D_i < 0 an equal and opposite impulse J along the contact normal n
!> (from j to i, through the closest axis points) is applied at the contact point:
!>     dv_i = +J n,  dv_j = -J n,  domega_i = J (r_i x n)/I_i,  domega_j = -J (r_j x n)/I_j,
!>     J = |D_i| / (dt K),  K = sum_k (1 + |r_k x n|^2 / I_k),
!> for bodies of equal (unit) mass and uniform density (transverse moment of inertia
!> I per unit mass, r_k the arm from the centre to the closest axis point). K makes the
!> normal relative velocity of the contact points grow by |D_i|/dt, i.e. the predicted
!> gap closes to first order. For two spheres r = 0, K = 2 and J = |D_i|/(2 dt): the
!> seed's delta_u. Momentum is conserved exactly (equal masses, opposite impulses);
!> a fibre contact away from the centre changes translation AND rotation.
!> Walls (Couette cell): a wall is an immovable body; the particle keeps a gap alpha/2
!> to it (half the particle-particle zone: the gap to its mirror image is alpha).
!>
!> Jacobi iteration: within one sweep every correction is computed from the same
!> predicted state, then all are applied, so the result does not depend on the order
!> of the particles nor on how they are split over MPI ranks (up to the round-off of
!> the rank sum). A pair is corrected once per sweep: i issues its worst pair (i, j*)
!> unless j* < i and j*'s own worst partner is i (then j* issues it). Ties in the worst gap are broken by the smaller index, so the
!> naive O(N^2) scan and the cell-list scan choose the same pairs and give bit-identical
!> corrections. The loop stops when every d_ij >= -tol_gap, with
!>     tol_gap = 64 eps max(L_cell)
!> (round-off of a distance between coordinates of size L; the seed's exact
!> criterion min d_ij >= 0 could loop forever on -1e-17), or after max_iter sweeps.
!>
!> MPI: resolve_contacts(..., first, last, reduce) issues only corrections originating
!> from particles first..last; the optional callback `reduce` (supplied by the driver,
!> an MPI_Allreduce; absent in serial) sums the correction arrays and counters and
!> takes the minimum of the gaps over ranks after each sweep. All particle data are
!> assumed replicated on every rank.
module fold_contacts
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_OVERLAP
   use fold_cell, only: cell_t, cell_min_image, cell_advance
   use fold_cell_list, only: cell_list_t, cell_list_build, cell_list_candidates
   use fold_particles, only: particle_set_t, particle_half_segment, FOLD_FIBRE, FOLD_SPHERE, FOLD_SPHEROID
   use fold_segment, only: capsule_contact
   use fold_kinematics, only: rotate_axis
   implicit none
   private

   !> No collision treatment (gaps are still measured for the statistics)
   integer(ip), parameter, public :: FOLD_CONTACT_NONE = 0
   !> The seed's loop with an O(N^2) search (reference)
   integer(ip), parameter, public :: FOLD_CONTACT_NAIVE = 1
   !> The seed's loop with cell lists, O(N) per sweep
   integer(ip), parameter, public :: FOLD_CONTACT_STRATEGY = 2
   !> Iteration cap reached: return FOLD_OVERLAP
   integer(ip), parameter, public :: FOLD_ON_CAP_STOP = 0
   !> Iteration cap reached: keep going, flag it in the statistics
   integer(ip), parameter, public :: FOLD_ON_CAP_CONTINUE = 1

   !> Options of the collision pass.
   type, public :: contact_config_t
      !> FOLD_CONTACT_NONE / NAIVE / STRATEGY
      integer(ip) :: mode = FOLD_CONTACT_STRATEGY
      !> Security zone alpha (>= 0) [m]
      real(dp) :: alpha = 0.0_dp
      !> Maximum number of correcting sweeps per step
      integer(ip) :: max_iter = 100
      !> FOLD_ON_CAP_STOP or FOLD_ON_CAP_CONTINUE
      integer(ip) :: on_cap = FOLD_ON_CAP_STOP
      !> Lubrication forces requested (applied by the Stokes coupling, see lubrication_force)
      logical :: lubrication = .false.
   end type contact_config_t

   !> What one collision pass did.
   type, public :: contact_stats_t
      !> Pair corrections applied (summed over sweeps)
      integer(i8) :: n_corrections = 0
      !> Correcting sweeps performed
      integer(ip) :: iterations = 0
      !> Smallest surface gap at t + dt after the pass, clipped at the range margin
      !> 2 alpha + R_max (exact whenever it is below that) [m]
      real(dp) :: min_gap = 0.0_dp
      !> min_gap / alpha (0 when alpha = 0) [-]
      real(dp) :: min_gap_over_alpha = 0.0_dp
      !> Distinct worst pairs (particle-particle or particle-wall) still violating the
      !> security zone after the pass
      integer(i8) :: pairs_left = 0
      !> Worst violation min(d_ij) = min(gap - alpha) after the pass (>= -tol_gap when resolved) [m]
      real(dp) :: worst_gap = 0.0_dp
      !> The iteration cap was reached
      logical :: capped = .false.
   end type contact_stats_t

   abstract interface
      !> Rank reduction called after every sweep: SUM over ranks of dv, domega and
      !> counts(1:2) = [pairs issued, pairs violating]; MIN over ranks of
      !> mins(1:2) = [smallest surface gap, worst violation].
      subroutine contact_reduce_i(dv, domega, counts, mins)
         import :: dp, i8
         real(dp), intent(inout) :: dv(:, :), domega(:, :)
         integer(i8), intent(inout) :: counts(:)
         real(dp), intent(inout) :: mins(:)
      end subroutine contact_reduce_i
   end interface
   public :: contact_reduce_i

   public :: resolve_contacts, contact_sweep, lubrication_force, transverse_inertia

   !> Index of the bottom / top wall as a "partner"
   integer(ip), parameter :: WALL_BOTTOM = -1, WALL_TOP = -2

contains

   !> Transverse moment of inertia per unit mass of a uniform body [m^2]:
   !> cylinder (3R^2 + L^2)/12 (2-D rectangle (4R^2 + L^2)/12); sphere 2R^2/5
   !> (disk R^2/2); spheroid (a^2 + b^2)/5 (ellipse (a^2 + b^2)/4), a = L/2, b = R.
   elemental function transverse_inertia(dim, shape, radius, length) result(inertia)
      integer(ip), intent(in) :: dim, shape
      real(dp), intent(in) :: radius, length
      real(dp) :: inertia
      select case (shape)
      case (FOLD_FIBRE)
         if (dim == 2) then
            inertia = (4.0_dp*radius**2 + length**2)/12.0_dp
         else
            inertia = (3.0_dp*radius**2 + length**2)/12.0_dp
         end if
      case (FOLD_SPHEROID)
         if (dim == 2) then
            inertia = (0.25_dp*length**2 + radius**2)/4.0_dp
         else
            inertia = (0.25_dp*length**2 + radius**2)/5.0_dp
         end if
      case default
         if (dim == 2) then
            inertia = 0.5_dp*radius**2
         else
            inertia = 0.4_dp*radius**2
         end if
      end select
   end function transverse_inertia

   !> Seed's lubrication force on sphere i from sphere j (physics.md section 3):
   !> F_ij = -(3/2) pi R^2 eta ((u_i - u_j).n_ij) / (|O_jO_i| - 2R) n_ij. The gap is
   !> floored at gap_min (the under-resolved gap the security zone guarantees) [N].
   pure function lubrication_force(radius, eta, dx, du, gap_min) result(f)
      !> Sphere radius R [m]
      real(dp), intent(in) :: radius
      !> Fluid viscosity [Pa s]
      real(dp), intent(in) :: eta
      !> O_i - O_j (minimum image) [m]
      real(dp), intent(in) :: dx(:)
      !> u_i - u_j [m/s]
      real(dp), intent(in) :: du(:)
      !> Smallest gap used in the denominator (> 0) [m]
      real(dp), intent(in) :: gap_min
      real(dp) :: f(size(dx))
      real(dp), parameter :: pi = acos(-1.0_dp)
      real(dp) :: dist, n(size(dx))
      dist = norm2(dx)
      n = dx/dist
      f = -1.5_dp*pi*radius**2*eta*dot_product(du, n)/max(dist - 2.0_dp*radius, gap_min)*n
   end function lubrication_force

   !> Predicted configuration at t + dt of every particle.
   pure subroutine predict(parts, dt, xp, pp)
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: dt
      real(dp), intent(out) :: xp(:, :), pp(:, :)
      integer(ip) :: k
      do k = 1, parts%n
         xp(:, k) = parts%x(:, k) + parts%v(:, k)*dt
         pp(:, k) = rotate_axis(parts%dim, parts%p(:, k), parts%omega(:, k), dt)
      end do
   end subroutine predict

   !> Geometry of pair (a, b) evaluated with the lower index first, so that the value
   !> is bit-identical whichever particle asks. Returns the surface distance, and the
   !> normal / arms oriented for the asking particle i (n from j to i).
   pure subroutine pair_geometry(cell, parts, xp, pp, hseg, i, j, dist, n, si, sj)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:)
      integer(ip), intent(in) :: i, j
      real(dp), intent(out) :: dist, n(:), si, sj
      integer(ip) :: a, b
      real(dp) :: r(parts%dim), sa, sb

      a = min(i, j)
      b = max(i, j)
      r = xp(:, a) - xp(:, b)
      call cell_min_image(cell, r)
      call capsule_contact(r, pp(:, a), hseg(a), parts%radius(a), pp(:, b), hseg(b), parts%radius(b), &
                           dist, n, sa, sb)
      if (i == a) then
         si = sa
         sj = sb
      else
         n = -n
         si = sb
         sj = sa
      end if
   end subroutine pair_geometry

   !> Lowest (bottom) or highest (top) point of a capsule axis: arm s and surface gap to the wall.
   pure subroutine wall_geometry(cell, parts, xp, pp, hseg, i, which, dist, n, si)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:)
      integer(ip), intent(in) :: i, which
      real(dp), intent(out) :: dist, n(:), si
      n = 0.0_dp
      if (which == WALL_BOTTOM) then
         si = -hseg(i)*sign(1.0_dp, pp(2, i))
         if (pp(2, i) == 0.0_dp) si = 0.0_dp
         dist = xp(2, i) + si*pp(2, i) - parts%radius(i)
         n(2) = 1.0_dp
      else
         si = hseg(i)*sign(1.0_dp, pp(2, i))
         if (pp(2, i) == 0.0_dp) si = 0.0_dp
         dist = cell%lengths(2) - (xp(2, i) + si*pp(2, i)) - parts%radius(i)
         n(2) = -1.0_dp
      end if
   end subroutine wall_geometry

   !> Worst partner of particle i: D_i = min_j (dist_ij - alpha_ij) and its index
   !> (walls: WALL_BOTTOM / WALL_TOP, with alpha/2); ties -> smaller index.
   !> Also the smallest surface gap seen (for the statistics).
   subroutine worst_partner(cell, parts, cfg, xp, pp, hseg, rc, use_cells, cl, cand, i, dmin, jbest, gapmin)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      type(contact_config_t), intent(in) :: cfg
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:), rc
      logical, intent(in) :: use_cells
      type(cell_list_t), intent(in) :: cl
      integer(ip), intent(inout) :: cand(:)
      integer(ip), intent(in) :: i
      real(dp), intent(out) :: dmin, gapmin
      integer(ip), intent(out) :: jbest
      integer(ip) :: nc, c, j
      real(dp) :: dist, n(parts%dim), si, sj, d

      dmin = huge(1.0_dp)
      gapmin = huge(1.0_dp)
      jbest = 0
      if (cell%walls) then
         call wall_geometry(cell, parts, xp, pp, hseg, i, WALL_TOP, dist, n, si)
         call consider(dist - 0.5_dp*cfg%alpha, dist, WALL_TOP)
         call wall_geometry(cell, parts, xp, pp, hseg, i, WALL_BOTTOM, dist, n, si)
         call consider(dist - 0.5_dp*cfg%alpha, dist, WALL_BOTTOM)
      end if
      if (use_cells) then
         call cell_list_candidates(cl, cell, xp(:, i), cand, nc)
      else
         nc = parts%n
         cand(1:nc) = [(j, j=1, parts%n)]
      end if
      do c = 1, nc
         j = cand(c)
         if (j == i) cycle
         call pair_geometry(cell, parts, xp, pp, hseg, i, j, dist, n, si, sj)
         ! pairs beyond the range cannot violate (dist >= rc - 2 max(h+R) > alpha):
         ! skipping them in BOTH modes keeps naive and cell-list results identical
         if (dist + hseg(i) + hseg(j) + parts%radius(i) + parts%radius(j) >= rc) cycle
         d = dist - cfg%alpha
         call consider(d, dist, j)
      end do
   contains
      subroutine consider(dval, gap, idx)
         real(dp), intent(in) :: dval, gap
         integer(ip), intent(in) :: idx
         gapmin = min(gapmin, gap)
         if (dval < dmin .or. (dval == dmin .and. idx < jbest)) then
            dmin = dval
            jbest = idx
         end if
      end subroutine consider
   end subroutine worst_partner

   !> One Jacobi sweep of the seed's loop for the particles first..last: accumulates
   !> the corrections into dv(dim, n), domega(3, n) (not applied), and reports
   !> n_issued, n_violating (distinct worst pairs with D_i < -tol), the smallest
   !> surface gap and the worst violation among them.
   subroutine contact_sweep(cell_t1, parts, dt, cfg, xp, pp, hseg, rc, tol, use_cells, cl, first, last, &
                            dv, domega, n_issued, n_violating, gapmin, worst)
      !> Cell at t + dt
      type(cell_t), intent(in) :: cell_t1
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: dt
      type(contact_config_t), intent(in) :: cfg
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:), rc, tol
      logical, intent(in) :: use_cells
      type(cell_list_t), intent(in) :: cl
      integer(ip), intent(in) :: first, last
      real(dp), intent(inout) :: dv(:, :), domega(:, :)
      integer(i8), intent(out) :: n_issued, n_violating
      real(dp), intent(out) :: gapmin, worst

      integer(ip) :: i, jbest, kbest
      integer(ip), allocatable :: cand(:)
      real(dp) :: dmin, g, dk, gk, dist, n(parts%dim), si, sj, kk, jimp, inv_i, inv_j, ci(3), cj(3)

      allocate (cand(parts%n))
      n_issued = 0
      n_violating = 0
      gapmin = huge(1.0_dp)
      worst = huge(1.0_dp)
      do i = first, last
         call worst_partner(cell_t1, parts, cfg, xp, pp, hseg, rc, use_cells, cl, cand, i, dmin, jbest, g)
         gapmin = min(gapmin, g)
         worst = min(worst, dmin)
         if (.not. (dmin < -tol)) cycle
         if (jbest > 0 .and. jbest < i) then
            ! mutual worst pair: issued once, by the lower index
            call worst_partner(cell_t1, parts, cfg, xp, pp, hseg, rc, use_cells, cl, cand, jbest, dk, kbest, gk)
            if (kbest == i) cycle
         end if
         n_violating = n_violating + 1
         if (cfg%mode == FOLD_CONTACT_NONE) cycle
         if (jbest > 0) then
            call pair_geometry(cell_t1, parts, xp, pp, hseg, i, jbest, dist, n, si, sj)
            ci = arm_cross(parts%dim, si*pp(:, i), n)
            cj = arm_cross(parts%dim, sj*pp(:, jbest), n)
            inv_i = 1.0_dp/transverse_inertia(parts%dim, parts%shape(i), parts%radius(i), parts%length(i))
            inv_j = 1.0_dp/transverse_inertia(parts%dim, parts%shape(jbest), parts%radius(jbest), parts%length(jbest))
            kk = 2.0_dp + sum(ci**2)*inv_i + sum(cj**2)*inv_j
            jimp = abs(dmin)/(dt*kk)
            dv(:, i) = dv(:, i) + jimp*n
            dv(:, jbest) = dv(:, jbest) - jimp*n
            domega(:, i) = domega(:, i) + jimp*inv_i*ci
            domega(:, jbest) = domega(:, jbest) - jimp*inv_j*cj
         else
            call wall_geometry(cell_t1, parts, xp, pp, hseg, i, jbest, dist, n, si)
            ci = arm_cross(parts%dim, si*pp(:, i), n)
            inv_i = 1.0_dp/transverse_inertia(parts%dim, parts%shape(i), parts%radius(i), parts%length(i))
            kk = 1.0_dp + sum(ci**2)*inv_i
            jimp = abs(dmin)/(dt*kk)
            dv(:, i) = dv(:, i) + jimp*n
            domega(:, i) = domega(:, i) + jimp*inv_i*ci
         end if
         n_issued = n_issued + 1
      end do
   end subroutine contact_sweep

   !> r x n as a 3-vector (2-D: only the z component).
   pure function arm_cross(dim, r, n) result(c)
      integer(ip), intent(in) :: dim
      real(dp), intent(in) :: r(:), n(:)
      real(dp) :: c(3)
      c = 0.0_dp
      if (dim == 2) then
         c(3) = r(1)*n(2) - r(2)*n(1)
      else
         c = [r(2)*n(3) - r(3)*n(2), r(3)*n(1) - r(1)*n(3), r(1)*n(2) - r(2)*n(1)]
      end if
   end function arm_cross

   !> Apply the collision strategy to the rigid velocities parts%v, parts%omega (see
   !> the module header). The cell is the cell at time t; gaps use it advanced by dt.
   subroutine resolve_contacts(cell, parts, dt, cfg, stats, stat, errmsg, first, last, reduce)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      !> Time step (> 0) [s]
      real(dp), intent(in) :: dt
      type(contact_config_t), intent(in) :: cfg
      type(contact_stats_t), intent(out) :: stats
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> Particles owned by this rank (default 1..n)
      integer(ip), intent(in), optional :: first, last
      !> Rank reduction after each sweep (default: none, serial)
      procedure(contact_reduce_i), optional :: reduce

      type(cell_t) :: cell1
      type(cell_list_t) :: cl
      integer(ip) :: i0, i1, k
      real(dp), allocatable :: xp(:, :), pp(:, :), hseg(:), dv(:, :), domega(:, :)
      real(dp) :: rc, margin, tol, mins(2)
      integer(i8) :: counts(2)
      logical :: use_cells

      stat = FOLD_INPUT_ERROR
      errmsg = ""
      stats = contact_stats_t()
      i0 = 1
      i1 = parts%n
      if (present(first)) i0 = first
      if (present(last)) i1 = last
      if (cfg%mode < FOLD_CONTACT_NONE .or. cfg%mode > FOLD_CONTACT_STRATEGY) then
         write (errmsg, '(a,i0,a)') "resolve_contacts: collisions mode ", cfg%mode, " (allowed 0 none, 1 naive, 2 strategy)"
         return
      end if
      if (.not. (dt > 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "resolve_contacts: dt must be > 0, got ", dt
         return
      end if
      if (.not. (cfg%alpha >= 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "resolve_contacts: alpha must be >= 0, got ", cfg%alpha
         return
      end if
      if (cfg%max_iter < 0) then
         write (errmsg, '(a,i0)') "resolve_contacts: contact_max_iter must be >= 0, got ", cfg%max_iter
         return
      end if
      if (cell%dim /= parts%dim) then
         write (errmsg, '(a,i0,a,i0)') "resolve_contacts: cell dim ", cell%dim, " /= particle dim ", parts%dim
         return
      end if
      if (i0 < 1 .or. i1 > parts%n .or. i0 > i1 + 1) then
         write (errmsg, '(a,i0,a,i0,a,i0)') "resolve_contacts: owned range ", i0, ":", i1, " outside 1:", parts%n
         return
      end if
      stat = FOLD_OK
      if (parts%n == 0) return

      cell1 = cell
      call cell_advance(cell1, dt)
      allocate (xp(parts%dim, parts%n), pp(parts%dim, parts%n), hseg(parts%n))
      allocate (dv(parts%dim, parts%n), domega(3, parts%n))
      hseg = particle_half_segment(parts%shape, parts%radius, parts%length)
      margin = 2.0_dp*cfg%alpha + maxval(parts%radius)
      rc = 2.0_dp*maxval(hseg + parts%radius) + margin
      tol = 64.0_dp*epsilon(1.0_dp)*maxval(cell%lengths(1:cell%dim))
      use_cells = cfg%mode /= FOLD_CONTACT_NAIVE

      do
         call predict(parts, dt, xp, pp)
         ! the cell list is rebuilt every sweep (positions moved); its setup also
         ! checks that the cell is larger than twice the range (unique image)
         call cell_list_build(cl, cell1, xp, rc, stat, errmsg)
         if (stat /= FOLD_OK) then
            errmsg = "resolve_contacts: "//trim(errmsg)
            return
         end if
         dv = 0.0_dp
         domega = 0.0_dp
         call contact_sweep(cell1, parts, dt, cfg, xp, pp, hseg, rc, tol, use_cells, cl, i0, i1, &
                            dv, domega, counts(1), counts(2), mins(1), mins(2))
         if (present(reduce)) call reduce(dv, domega, counts, mins)
         stats%min_gap = min(mins(1), margin)
         stats%worst_gap = min(mins(2), margin - cfg%alpha)
         stats%pairs_left = counts(2)
         if (counts(2) == 0 .or. cfg%mode == FOLD_CONTACT_NONE) exit
         if (stats%iterations >= cfg%max_iter) then
            stats%capped = .true.
            exit
         end if
         do k = 1, parts%n
            parts%v(:, k) = parts%v(:, k) + dv(:, k)
            if (parts%dim == 2) then
               parts%omega(3, k) = parts%omega(3, k) + domega(3, k)
            else
               parts%omega(:, k) = parts%omega(:, k) + domega(:, k)
            end if
         end do
         stats%iterations = stats%iterations + 1
         stats%n_corrections = stats%n_corrections + counts(1)
      end do
      if (cfg%alpha > 0.0_dp) stats%min_gap_over_alpha = stats%min_gap/cfg%alpha
      if (stats%capped .and. cfg%on_cap == FOLD_ON_CAP_STOP) then
         stat = FOLD_OVERLAP
         write (errmsg, '(a,i0,a,i0,a,es11.3,a)') "resolve_contacts: ", stats%pairs_left, &
            " pairs still inside the security zone after ", stats%iterations, &
            " sweeps (worst gap - alpha = ", stats%worst_gap, "); raise contact_max_iter, lower dt or the packing"
      end if
   end subroutine resolve_contacts

end module fold_contacts
