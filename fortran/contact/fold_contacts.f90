!> The seed's collision strategy (Laure, Megally & Coupez; docs/physics.md#collision-strategy).
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
!> Target beyond the zone. Each correction aims at d_ij = +push, not at d_ij = 0:
!>     J = (|D_i| + push) / (dt K),   push = max(1e-3 alpha, 16 tol_gap).
!> Why: aiming at exactly zero leaves every corrected pair on the edge of the zone,
!> where the next sweep sees -1e-14 of round-off, or the second-order residue of the
!> exact rotation that the linearised impulse ignores (a fibre turned by dtheta misses
!> by ~ h dtheta^2 / 2), and corrects it again: the loop then only converges
!> geometrically and a residue just past tol_gap can outlive any cap (the 256-fibre
!> default scene stalled at step 375 on -5.7e-14 after 100 sweeps). A push well above
!> round-off and above that residue lets a corrected pair leave the loop after one or
!> two sweeps. 1e-3 alpha is physically invisible (alpha is itself a mesh-dependent
!> numerical margin) yet ~1e9 times the round-off of a gap; 16 tol_gap keeps the push
!> above round-off when alpha = 0. Two spheres head on: delta = (|D| + push)/(2 dt),
!> i.e. the seed's |D|/(2 dt) plus push/(2 dt), and the pair ends at gap alpha + push.
!>
!> Later sweeps: J = (2 |D_i| + push) / (dt K). The first sweep applies the seed's
!> rule to every violating pair; whatever still violates afterwards does so because
!> simultaneous (Jacobi) corrections interfered: a fibre squeezed between two others
!> is pushed both ways, the pushes on it cancel and each pair gets only half its
!> correction, so the residue halves per sweep (measured: 6 fibres of the stalled
!> step above oscillating 20 sweeps; 50 % disks up to 164 sweeps). Doubling the later
!> corrections resolves that symmetric case in one more sweep; an overshoot only
!> opens a gap (the constraint is one-sided), never a new violation of that pair.
!> Measured on the 256-fibre scene: sweeps per step median 8 -> 4, max 20 -> 8; seed
!> disks: median 41 -> 8, max 164 -> 18 (factor 1.5: 4/7 and 10/61). A pair that is
!> resolved in the first sweep (every isolated collision) never sees the factor.
!>
!> Jacobi iteration: within one sweep every correction is computed from the same
!> predicted state, then all are applied, so the result does not depend on the order
!> of the particles nor on how they are split over MPI ranks (up to the round-off of
!> the rank sum). A pair is corrected once per sweep: i issues its worst pair (i, j*)
!> unless j* < i and j*'s own worst partner is i (then j* issues it). Ties in the
!> worst gap are broken by the smaller index, so the outcome does not depend on the
!> order in which pairs were found: the naive O(N^2) scan and the cell-list scan give
!> bit-identical corrections. The loop stops when every d_ij >= -tol_gap, with
!>     tol_gap = 64 eps max(L_cell)
!> (round-off of a distance between coordinates of size L; the seed's exact
!> criterion min d_ij >= 0 could loop forever on -1e-17), or after max_iter sweeps.
!>
!> Naive (the reference, docs/physics.md#sphere-collisions): the seed's literal loop. EVERY sweep
!> rescans all N(N-1)/2 pairs by the O(N^2) double loop at the current prediction
!> (minimum image of each pair, then the segment distance of those whose centre
!> distance minus both extents is below the cutoff) to find each D_i. Nothing is
!> kept from one sweep to the next, so its cost is O(N^2) per sweep.
!>
!> Strategy: candidate pairs (Verlet list; Allen & Tildesley 2017, Computer Simulation
!> of Liquids, 2nd ed., section 5.2). ONE list is built per pass with the cell lists,
!> of the pairs whose surface distance at the predicted configuration is below
!>     cutoff = alpha + skin,   skin = alpha + R_max (default);
!> the sweeps visit only the list and re-evaluate only the pairs with a particle
!> corrected in the previous sweep. Exactness: moving every point of a capsule by at most delta changes
!> its distance to any other set by at most delta (a distance between sets is
!> 1-Lipschitz in each set's displacement). Since the list was built, corrections
!> have moved every axis point s pp_k + xp_k (|s| <= h_k) of particle k by at most
!>     delta_k = |xp_k - xp0_k| + h_k |pp_k - pp0_k|,
!> so an unlisted pair still has dist >= cutoff - delta_i - delta_j. The list is rebuilt
!> as soon as max_k delta_k > skin/2, so an unlisted pair always has dist >= alpha: it
!> can neither violate nor be the worst partner of a violating particle, and the
!> corrections do not depend on the skin. Gap statistics are exact below
!> cutoff - 2 max delta_k (>= alpha) and clipped there. The worst partner of a
!> violating particle is therefore the same pair in both modes (ties -> smaller
!> index), so naive and strategy give bit-identical corrections; only the list
!> statistics (builds, size) and the clipping of the gap statistics differ.
!>
!> MPI: resolve_contacts(..., first, last, reduce) issues only corrections originating
!> from particles first..last; the optional callback `reduce` (supplied by the driver,
!> an MPI_Allreduce; absent in serial) sums the correction arrays and counters and
!> takes the minimum of the gaps over ranks after each sweep. All particle data are
!> assumed replicated on every rank, and so are the pair list and the pair gaps (the
!> mutual check needs the worst partner of non-owned particles; O(N) per build with
!> cells, O(pairs touched) per sweep). The rebuild decision depends only on the
!> reduced velocities, so every rank takes it identically.
module fold_contacts
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_OVERLAP
   use fold_cell, only: cell_t, cell_min_image, cell_advance
   use fold_cell_list, only: cell_list_t, cell_list_build, cell_list_candidates, bin_sort_t, cell_list_sort, &
                             cell_list_has_image_stencil, cell_list_image_stencil, STENCIL_MAX
   use fold_particles, only: particle_set_t, particle_half_segment, FOLD_FIBRE, FOLD_SPHERE, FOLD_SPHEROID
   use fold_segment, only: capsule_contact
   use fold_kinematics, only: rotate_axis
   implicit none
   private

   !> No collision treatment (gaps are still measured for the statistics)
   integer(ip), parameter, public :: FOLD_CONTACT_NONE = 0
   !> The seed's loop, candidate pairs from an O(N^2) double loop (reference)
   integer(ip), parameter, public :: FOLD_CONTACT_NAIVE = 1
   !> The seed's loop, candidate pairs from cell lists (O(N) per list build)
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
      !> Lubrication requested: not used by the contact pass; the Stokes step applies it
      !> (fold_lubrication, fold_stokes_step)
      logical :: lubrication = .false.
      !> Verlet skin of the candidate-pair list [m]; < 0 (default): alpha + R_max.
      !> Any value >= 0 gives the same corrections (the list is exact); a small one
      !> only forces more rebuilds (tests use it to check exactly that). A larger one
      !> widens the search range, which the cell must still exceed twice.
      real(dp) :: skin = -1.0_dp
   end type contact_config_t

   !> What one collision pass did.
   type, public :: contact_stats_t
      !> Pair corrections applied (summed over sweeps)
      integer(i8) :: n_corrections = 0
      !> Correcting sweeps performed
      integer(ip) :: iterations = 0
      !> Smallest surface gap at t + dt after the pass, clipped at the list's exact
      !> range alpha + skin - 2 max delta_k (>= alpha; 2 alpha + R_max with the default
      !> skin before any correction), exact whenever it is below that [m]
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
      !> Margin beyond alpha each correction aims at, max(1e-3 alpha, 16 tol_gap) [m]
      real(dp) :: push = 0.0_dp
      !> Candidate-pair lists built during the pass (1 unless a rebuild was needed)
      integer(ip) :: list_builds = 0
      !> Pairs in the last list
      integer(i8) :: list_pairs = 0
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

   public :: resolve_contacts, transverse_inertia, contact_search_range

   !> Index of the bottom / top wall as a "partner"
   integer(ip), parameter :: WALL_BOTTOM = -1, WALL_TOP = -2
   !> push = max(PUSH_ALPHA alpha, PUSH_TOL tol_gap), see the module header
   real(dp), parameter :: PUSH_ALPHA = 1.0e-3_dp, PUSH_TOL = 16.0_dp
   !> Over-relaxation of the corrections issued after the first sweep (module header)
   real(dp), parameter :: RELAX_LATER = 2.0_dp

   !> Candidate pairs (a < b) of one pass with their geometry at the current prediction.
   type :: pair_list_t
      integer(ip) :: n = 0
      !> ab(:, k) = [a, b], a < b
      integer(ip), allocatable :: ab(:, :)
      !> Surface distance [m]
      real(dp), allocatable :: dist(:)
      !> Unit normal from b to a
      real(dp), allocatable :: nrm(:, :)
      !> Closest-point arms on a and b [m]
      real(dp), allocatable :: arm(:, :)
   end type pair_list_t

   !> Worst partner of every particle at the current prediction.
   type :: worst_t
      !> D_k = min_j d_kj (huge when k has no listed pair and no wall) [m]
      real(dp), allocatable :: d(:)
      !> Partner index (WALL_BOTTOM / WALL_TOP for walls, 0 for none)
      integer(ip), allocatable :: j(:)
      !> Index in the pair list of that pair (0 for walls or none)
      integer(ip), allocatable :: k(:)
   end type worst_t

contains

   !> Transverse moment of inertia per unit mass of a uniform body [m^2]:
   !> cylinder (3R^2 + L^2)/12 (2-D rectangle (4R^2 + L^2)/12); sphere 2R^2/5
   !> (disk R^2/2); spheroid (a^2 + b^2)/5 (ellipse (a^2 + b^2)/4), a = L/2, b = R.
   elemental function transverse_inertia(dim, shape, radius, length) result(inertia)
      integer(ip), intent(in) :: dim, shape
      real(dp), intent(in) :: radius, length
      real(dp) :: inertia
      logical :: plane
      plane = dim == 2
      select case (shape)
      case (FOLD_FIBRE)
         inertia = (merge(4.0_dp, 3.0_dp, plane)*radius**2 + length**2)/12.0_dp
      case (FOLD_SPHEROID)
         inertia = (0.25_dp*length**2 + radius**2)/merge(4.0_dp, 5.0_dp, plane)
      case default
         inertia = merge(0.5_dp, 0.4_dp, plane)*radius**2
      end select
   end function transverse_inertia

   !> Centre-distance range of the contact search, 2 max_k (h_k + R_k) + alpha + skin
   !> (h_k the half segment; skin < 0: the default alpha + R_max): every pair whose
   !> surface distance is below the cutoff alpha + skin has centres closer than this.
   !> The periodic cell must be thicker than twice it (unique minimum image) [m].
   pure function contact_search_range(shape, radius, length, alpha, skin) result(rc)
      integer(ip), intent(in) :: shape(:)
      real(dp), intent(in) :: radius(:), length(:)
      !> Security zone [m]
      real(dp), intent(in) :: alpha
      !> Verlet skin (< 0: default) [m]
      real(dp), intent(in) :: skin
      real(dp) :: rc, s
      rc = 0.0_dp
      if (size(shape) == 0) return
      s = skin
      if (s < 0.0_dp) s = alpha + maxval(radius)
      rc = 2.0_dp*maxval(particle_half_segment(shape, radius, length) + radius) + (alpha + s)
   end function contact_search_range

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

   !> Geometry of pair (a, b), a < b, at the predicted configuration: surface distance,
   !> unit normal from b to a, closest-point arms. Always evaluated in this order, so
   !> the value is bit-identical however (and by whichever search) the pair was found.
   pure subroutine pair_geometry(cell, parts, xp, pp, hseg, a, b, dist, n, sa, sb)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:)
      integer(ip), intent(in) :: a, b
      real(dp), intent(out) :: dist, n(:), sa, sb
      real(dp) :: r(3), nn(3)
      integer :: d

      d = parts%dim
      r(1:d) = xp(:, a) - xp(:, b)
      call cell_min_image(cell, r(1:d))
      call capsule_contact(r(1:d), pp(:, a), hseg(a), parts%radius(a), pp(:, b), hseg(b), parts%radius(b), &
                           dist, nn(1:d), sa, sb)
      n = nn(1:d)
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

   !> Append pair (a, b), a < b, to the list when its surface distance is below cutoff.
   pure subroutine list_consider(cell, parts, xp, pp, hseg, a, b, cutoff, list)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:), cutoff
      integer(ip), intent(in) :: a, b
      type(pair_list_t), intent(inout) :: list
      call consider_pair(cell, parts%dim, xp(:, a), pp(:, a), hseg(a), parts%radius(a), &
                         xp(:, b), pp(:, b), hseg(b), parts%radius(b), a, b, cutoff, list)
   end subroutine list_consider

   !> list_consider from the data of the two particles (centre, axis, half segment,
   !> radius; a < b): the same operations in the same order as pair_geometry, so the
   !> listed geometry is bit-identical to it whichever copy of the data is read.
   pure subroutine consider_pair(cell, dim, xa, pa, ha, ra, xb, pb, hb, rb, a, b, cutoff, list)
      type(cell_t), intent(in) :: cell
      integer(ip), intent(in) :: dim
      real(dp), intent(in) :: xa(:), pa(:), ha, ra, xb(:), pb(:), hb, rb, cutoff
      integer(ip), intent(in) :: a, b
      type(pair_list_t), intent(inout) :: list
      ! fixed-size locals: an automatic array would cost a heap allocation per pair
      real(dp) :: r(3), dist, n(3), sa, sb

      r(1:dim) = xa(1:dim) - xb(1:dim)
      call cell_min_image(cell, r(1:dim))
      ! centre distance minus both capsule extents is a lower bound of the surface
      ! distance: most pairs are rejected without the segment computation
      if (norm2(r(1:dim)) - (ha + ra + hb + rb) >= cutoff) return
      call capsule_contact(r(1:dim), pa, ha, ra, pb, hb, rb, dist, n(1:dim), sa, sb)
      if (.not. (dist < cutoff)) return
      if (list%n == size(list%dist)) call list_grow(list)
      list%n = list%n + 1
      list%ab(1, list%n) = a
      list%ab(2, list%n) = b
      list%dist(list%n) = dist
      list%nrm(:, list%n) = n(1:dim)
      list%arm(1, list%n) = sa
      list%arm(2, list%n) = sb
   end subroutine consider_pair

   !> Double the capacity of a pair list.
   pure subroutine list_grow(list)
      type(pair_list_t), intent(inout) :: list
      integer(ip), allocatable :: ab(:, :)
      real(dp), allocatable :: dist(:), nrm(:, :), arm(:, :)
      integer(ip) :: cap
      cap = 2*max(size(list%dist), 8)
      allocate (ab(2, cap), dist(cap), nrm(size(list%nrm, 1), cap), arm(2, cap))
      ab(:, 1:list%n) = list%ab(:, 1:list%n)
      dist(1:list%n) = list%dist(1:list%n)
      nrm(:, 1:list%n) = list%nrm(:, 1:list%n)
      arm(:, 1:list%n) = list%arm(:, 1:list%n)
      call move_alloc(ab, list%ab)
      call move_alloc(dist, list%dist)
      call move_alloc(nrm, list%nrm)
      call move_alloc(arm, list%arm)
   end subroutine list_grow

   !> The candidate pairs: every pair whose surface distance at the prediction (xp, pp)
   !> is below cutoff, found with the cell lists (use_cells) or the O(N^2) double loop
   !> (the reference). The cell list is built in both modes: its setup checks that the
   !> cell exceeds twice the range rc (unique minimum image).
   !>
   !> Cells, in a sheared or fixed cell with at least three bins per periodic direction
   !> (cell_list_has_image_stencil; the others take the generic candidate scan): the
   !> particles are counting-sorted by bin and their data copied in that order, so a
   !> bin's neighbours are read from a few contiguous stretches of memory (particle
   !> indices are random in space: reading by index fetches every neighbour from
   !> elsewhere, which made the cost per particle grow once the data left the cache).
   !> Every pair is visited once, from its lower slot, with the image translation of
   !> the neighbour bin: a pair whose centres are farther apart than the two extents
   !> plus cutoff plus a margin far above round-off is rejected from that image
   !> without the minimum image; all others go through consider_pair, the same exact
   !> operations as the double loop. The list therefore holds exactly the pairs of the
   !> double loop with bit-identical geometry (ordered by bin instead of by index:
   !> nothing downstream depends on the order, see find_worst).
   subroutine build_pair_list(cell, parts, xp, pp, hseg, cutoff, rc, use_cells, list, stat, errmsg)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: xp(:, :), pp(:, :), hseg(:), cutoff, rc
      logical, intent(in) :: use_cells
      type(pair_list_t), intent(inout) :: list
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(cell_list_t) :: cl
      type(bin_sort_t) :: bs
      integer(ip), allocatable :: cand(:)
      real(dp), allocatable :: xs(:, :), ps(:, :), ext(:), hs(:), rs(:)
      integer(ip) :: a, b, c, nc, ia, jb, bin, t, dim, sbins(STENCIL_MAX)
      integer :: nst
      real(dp) :: shift(3, STENCIL_MAX), d(3), qa(3), ea, margin, pc(3), cc
      ! |p_a x p_b|^2 above which the line distance is used (its round-off ~ eps |d| / |c|)
      real(dp), parameter :: SKEW_MIN = 1.0e-8_dp

      if (.not. allocated(list%dist)) then
         allocate (list%ab(2, 4*parts%n), list%dist(4*parts%n), list%nrm(parts%dim, 4*parts%n), &
                   list%arm(2, 4*parts%n))
      end if
      list%n = 0
      call cell_list_build(cl, cell, xp, rc, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (use_cells .and. cell_list_has_image_stencil(cl, cell)) then
         dim = parts%dim
         call cell_list_sort(cl, cell, xp, bs)
         allocate (xs(dim, parts%n), ps(dim, parts%n), hs(parts%n), rs(parts%n), ext(parts%n))
         do ia = 1, parts%n
            a = bs%id(ia)
            xs(:, ia) = xp(:, a)
            ps(:, ia) = pp(:, a)
            hs(ia) = hseg(a)
            rs(ia) = parts%radius(a)
            ext(ia) = hseg(a) + parts%radius(a)
         end do
         ! round-off of wrapped coordinates is ~ eps L; 1e-9 L can never reject a pair
         ! the exact test would keep
         margin = 1.0e-9_dp*(sum(cell%lengths(1:dim)) + rc)
         do bin = 1, int(size(bs%first) - 1, ip)
            do ia = bs%first(bin), bs%first(bin + 1) - 1
               call cell_list_image_stencil(cl, cell, bs%xw(:, ia), nst, sbins, shift)
               do t = 1, nst
                  ! the query seen from the images in bin sbins(t); all three components
                  ! (2-D: the third is 0 for both), in scalars for the inner loop
                  qa = bs%xw(:, ia) - shift(:, t)
                  ea = ext(ia) + cutoff + margin
                  ! pairs are taken from their lower slot
                  do jb = max(bs%first(sbins(t)), ia + 1), bs%first(sbins(t) + 1) - 1
                     d = qa - bs%xw(:, jb)
                     if (d(1)**2 + d(2)**2 + d(3)**2 >= (ea + ext(jb))**2) cycle
                     if (dim == 3) then
                        ! the distance |d.pc|/|pc| of the two axis lines (pc = p_a x p_b)
                        ! bounds the axis distance from below: skew pairs far apart
                        ! skip the segment computation (not near-parallel ones: round-off)
                        pc = [ps(2, ia)*ps(3, jb) - ps(3, ia)*ps(2, jb), ps(3, ia)*ps(1, jb) - ps(1, ia)*ps(3, jb), &
                             ps(1, ia)*ps(2, jb) - ps(2, ia)*ps(1, jb)]
                        cc = pc(1)**2 + pc(2)**2 + pc(3)**2
                        if (cc > SKEW_MIN .and. (d(1)*pc(1) + d(2)*pc(2) + d(3)*pc(3))**2 > &
                            (rs(ia) + rs(jb) + cutoff + margin)**2*cc) cycle
                     end if
                     if (bs%id(ia) < bs%id(jb)) then
                        call consider_pair(cell, dim, xs(:, ia), ps(:, ia), hs(ia), rs(ia), xs(:, jb), ps(:, jb), &
                                           hs(jb), rs(jb), bs%id(ia), bs%id(jb), cutoff, list)
                     else
                        call consider_pair(cell, dim, xs(:, jb), ps(:, jb), hs(jb), rs(jb), xs(:, ia), ps(:, ia), &
                                           hs(ia), rs(ia), bs%id(jb), bs%id(ia), cutoff, list)
                     end if
                  end do
               end do
            end do
         end do
      else if (use_cells) then
         allocate (cand(parts%n))
         do a = 1, parts%n
            call cell_list_candidates(cl, cell, xp(:, a), cand, nc)
            do c = 1, nc
               b = cand(c)
               if (b > a) call list_consider(cell, parts, xp, pp, hseg, a, b, cutoff, list)
            end do
         end do
      else
         do a = 1, parts%n
            do b = a + 1, parts%n
               call list_consider(cell, parts, xp, pp, hseg, a, b, cutoff, list)
            end do
         end do
      end if
   end subroutine build_pair_list

   !> Worst partner of every particle, D_k = min_j (dist_kj - alpha_kj) over the listed
   !> pairs and the walls (alpha/2 to a wall); ties -> smaller partner index, so the
   !> result does not depend on the order of the list. Also the smallest surface gap.
   subroutine find_worst(cell, parts, alpha, xp, pp, hseg, list, w, gapmin)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: alpha, xp(:, :), pp(:, :), hseg(:)
      type(pair_list_t), intent(in) :: list
      type(worst_t), intent(inout) :: w
      real(dp), intent(out) :: gapmin
      integer(ip) :: k, a, b
      real(dp) :: dist, n(parts%dim), s, d

      w%d = huge(1.0_dp)
      w%j = 0
      w%k = 0
      gapmin = huge(1.0_dp)
      if (cell%walls) then
         do k = 1, parts%n
            call wall_geometry(cell, parts, xp, pp, hseg, k, WALL_TOP, dist, n, s)
            gapmin = min(gapmin, dist)
            call consider(k, dist - 0.5_dp*alpha, WALL_TOP, 0)
            call wall_geometry(cell, parts, xp, pp, hseg, k, WALL_BOTTOM, dist, n, s)
            gapmin = min(gapmin, dist)
            call consider(k, dist - 0.5_dp*alpha, WALL_BOTTOM, 0)
         end do
      end if
      do k = 1, list%n
         a = list%ab(1, k)
         b = list%ab(2, k)
         gapmin = min(gapmin, list%dist(k))
         d = list%dist(k) - alpha
         call consider(a, d, b, k)
         call consider(b, d, a, k)
      end do
   contains
      subroutine consider(i, dval, idx, kk)
         integer(ip), intent(in) :: i, idx, kk
         real(dp), intent(in) :: dval
         if (dval < w%d(i) .or. (dval == w%d(i) .and. idx < w%j(i))) then
            w%d(i) = dval
            w%j(i) = idx
            w%k(i) = kk
         end if
      end subroutine consider
   end subroutine find_worst

   !> One Jacobi sweep of the seed's loop for the particles first..last, from the worst
   !> partners w: accumulates the corrections into dv(dim, n), domega(3, n) (not
   !> applied), and reports n_issued, n_violating (distinct worst pairs with
   !> D_i < -tol) and the worst D_i of the owned particles.
   subroutine issue_corrections(cell, parts, dt, cfg, push, relax, tol, xp, pp, hseg, list, w, first, last, &
                                dv, domega, n_issued, n_violating, worst)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: dt
      type(contact_config_t), intent(in) :: cfg
      real(dp), intent(in) :: push, relax, tol, xp(:, :), pp(:, :), hseg(:)
      type(pair_list_t), intent(in) :: list
      type(worst_t), intent(in) :: w
      integer(ip), intent(in) :: first, last
      real(dp), intent(inout) :: dv(:, :), domega(:, :)
      integer(i8), intent(out) :: n_issued, n_violating
      real(dp), intent(out) :: worst

      integer(ip) :: i, j, k
      real(dp) :: dist, n(parts%dim), si, sj, kk, jimp, inv_i, inv_j, ci(3), cj(3)

      n_issued = 0
      n_violating = 0
      worst = huge(1.0_dp)
      do i = first, last
         worst = min(worst, w%d(i))
         if (.not. (w%d(i) < -tol)) cycle
         j = w%j(i)
         ! mutual worst pair: issued once, by the lower index
         if (j > 0 .and. j < i) then
            if (w%j(j) == i) cycle
         end if
         n_violating = n_violating + 1
         if (cfg%mode == FOLD_CONTACT_NONE) cycle
         inv_i = 1.0_dp/transverse_inertia(parts%dim, parts%shape(i), parts%radius(i), parts%length(i))
         if (j > 0) then
            k = w%k(i)
            if (i == list%ab(1, k)) then
               n = list%nrm(:, k)
               si = list%arm(1, k)
               sj = list%arm(2, k)
            else
               n = -list%nrm(:, k)
               si = list%arm(2, k)
               sj = list%arm(1, k)
            end if
            ci = arm_cross(parts%dim, si*pp(:, i), n)
            cj = arm_cross(parts%dim, sj*pp(:, j), n)
            inv_j = 1.0_dp/transverse_inertia(parts%dim, parts%shape(j), parts%radius(j), parts%length(j))
            kk = 2.0_dp + sum(ci**2)*inv_i + sum(cj**2)*inv_j
            jimp = (relax*abs(w%d(i)) + push)/(dt*kk)
            dv(:, i) = dv(:, i) + jimp*n
            dv(:, j) = dv(:, j) - jimp*n
            domega(:, i) = domega(:, i) + jimp*inv_i*ci
            domega(:, j) = domega(:, j) - jimp*inv_j*cj
         else
            call wall_geometry(cell, parts, xp, pp, hseg, i, j, dist, n, si)
            ci = arm_cross(parts%dim, si*pp(:, i), n)
            kk = 1.0_dp + sum(ci**2)*inv_i
            jimp = (relax*abs(w%d(i)) + push)/(dt*kk)
            dv(:, i) = dv(:, i) + jimp*n
            domega(:, i) = domega(:, i) + jimp*inv_i*ci
         end if
         n_issued = n_issued + 1
      end do
   end subroutine issue_corrections

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
      type(pair_list_t) :: list
      type(worst_t) :: w
      integer(ip) :: i0, i1, k, a, b
      real(dp), allocatable :: xp(:, :), pp(:, :), xp0(:, :), pp0(:, :), hseg(:), dv(:, :), domega(:, :), delta(:)
      logical, allocatable :: moved(:)
      real(dp) :: rc, skin, cutoff, reach, tol, push, mins(2), relax
      integer(i8) :: counts(2)
      logical :: use_cells, rebuild

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
      allocate (xp(parts%dim, parts%n), pp(parts%dim, parts%n), xp0(parts%dim, parts%n), pp0(parts%dim, parts%n))
      allocate (hseg(parts%n), dv(parts%dim, parts%n), domega(3, parts%n), delta(parts%n), moved(parts%n))
      allocate (w%d(parts%n), w%j(parts%n), w%k(parts%n))
      hseg = particle_half_segment(parts%shape, parts%radius, parts%length)
      skin = cfg%skin
      if (skin < 0.0_dp) skin = cfg%alpha + maxval(parts%radius)
      cutoff = cfg%alpha + skin
      rc = contact_search_range(parts%shape, parts%radius, parts%length, cfg%alpha, cfg%skin)
      tol = 64.0_dp*epsilon(1.0_dp)*maxval(cell%lengths(1:cell%dim))
      push = max(PUSH_ALPHA*cfg%alpha, PUSH_TOL*tol)
      stats%push = push
      use_cells = cfg%mode /= FOLD_CONTACT_NAIVE

      call predict(parts, dt, xp, pp)
      rebuild = .true.
      do
         if (rebuild) then
            call build_pair_list(cell1, parts, xp, pp, hseg, cutoff, rc, use_cells, list, stat, errmsg)
            if (stat /= FOLD_OK) then
               errmsg = "resolve_contacts: "//trim(errmsg)
               return
            end if
            stats%list_builds = stats%list_builds + 1
            stats%list_pairs = list%n
            xp0 = xp
            pp0 = pp
            delta = 0.0_dp
         end if
         ! every pair closer than reach is listed (module header)
         reach = cutoff - 2.0_dp*maxval(delta)
         call find_worst(cell1, parts, cfg%alpha, xp, pp, hseg, list, w, mins(1))
         dv = 0.0_dp
         domega = 0.0_dp
         ! sweep 1: the seed's rule; later sweeps undo Jacobi interference (see header)
         relax = 1.0_dp
         if (stats%iterations > 0) relax = RELAX_LATER
         call issue_corrections(cell1, parts, dt, cfg, push, relax, tol, xp, pp, hseg, list, w, i0, i1, &
                                dv, domega, counts(1), counts(2), mins(2))
         if (present(reduce)) call reduce(dv, domega, counts, mins)
         stats%min_gap = min(mins(1), reach)
         stats%worst_gap = min(mins(2), reach - cfg%alpha)
         stats%pairs_left = counts(2)
         if (counts(2) == 0 .or. cfg%mode == FOLD_CONTACT_NONE) exit
         if (stats%iterations >= cfg%max_iter) then
            stats%capped = .true.
            exit
         end if
         do k = 1, parts%n
            moved(k) = any(dv(:, k) /= 0.0_dp) .or. any(domega(:, k) /= 0.0_dp)
            if (.not. moved(k)) cycle
            parts%v(:, k) = parts%v(:, k) + dv(:, k)
            if (parts%dim == 2) then
               parts%omega(3, k) = parts%omega(3, k) + domega(3, k)
            else
               parts%omega(:, k) = parts%omega(:, k) + domega(:, k)
            end if
            ! new prediction of the corrected particles only (the others are unchanged)
            xp(:, k) = parts%x(:, k) + parts%v(:, k)*dt
            pp(:, k) = rotate_axis(parts%dim, parts%p(:, k), parts%omega(:, k), dt)
            delta(k) = norm2(xp(:, k) - xp0(:, k)) + hseg(k)*norm2(pp(:, k) - pp0(:, k))
         end do
         stats%iterations = stats%iterations + 1
         stats%n_corrections = stats%n_corrections + counts(1)
         ! Verlet criterion: rebuild before an unlisted pair could come within alpha;
         ! naive: the seed's loop rescans every pair at every sweep
         rebuild = maxval(delta) > 0.5_dp*skin .or. .not. use_cells
         if (.not. rebuild) then
            do k = 1, list%n
               a = list%ab(1, k)
               b = list%ab(2, k)
               if (moved(a) .or. moved(b)) &
                  call pair_geometry(cell1, parts, xp, pp, hseg, a, b, list%dist(k), list%nrm(:, k), &
                                     list%arm(1, k), list%arm(2, k))
            end do
         end if
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
