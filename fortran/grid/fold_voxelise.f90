!> Partial-volume characteristic function chi of the particles on the grid.
!>
!> chi of a voxel is the fraction of its volume covered by particles (between 0 and 1,
!> docs/physics.md#characteristic-function-by-voxelisation), so a particle can move by
!> less than one voxel and its discrete volume changes smoothly. The fraction is the mean over S^dim
!> sub-voxel points of a smooth ramp H(1/2 - phi/w) of the signed distance phi
!> (w = h/S the sub-voxel size), H(t) = 10t^3 - 15t^4 + 6t^5 on [0, 1] (0 below,
!> 1 above). H(1 - t) = 1 - H(t), so for a plane interface the ramp integrates
!> to the exact covered volume like a linear one, curved interfaces err by
!> O(w^2/R); being C2 (a clamped linear ramp is only C0) it makes chi, hence
!> the rigid velocities, twice differentiable in the particle position and
!> orientation, which the second-order time stepping needs to show its order.
!> Signed distances: sphere |r| - R; flat cylinder (exact, radius R, length L);
!> capped fibre = the contact capsule of fold_segment (segment of half-length L/2, radius R);
!> prolate spheroid (a = L/2, b = R) by the first-order estimate
!> (q - 1)/|grad q|, q^2 = z^2/a^2 + rho^2/b^2, exact on the surface. 2-D: the same
!> formulas in the plane (rectangle 2R x L, disk, ellipse).
!> Each particle visits only the voxels of its bounding box, in unwrapped lattice
!> indices around its centre: the periodic minimum image is implicit (voxel
!> indices are wrapped for storage only), so the cost is proportional to the
!> voxels the particle touches, and voxels far from the surface (|phi| larger
!> than the voxel half-diagonal + w) are classified without sub-sampling. A fibre
!> skips the rows of its box (lattice direction 1) that pass farther from its axis
!> segment than its radius + that margin, so an oblique fibre visits the voxels near it,
!> not its whole box. Every skip only avoids work whose result is known (chi is the same
!> bit for bit): a fibre's signed distance is the exact Euclidean one, 1-Lipschitz, so a
!> bound at a row or a voxel centre widened by the sub-points' reach holds where it skips.
!> Added shells kept apart (optional shell_gap g >= 0, with fibre_radius_scale s > 1; a negative
!> g, the default, lets them overlap). The shell
!> of radius (s - 1) R added to a fibre k is its coverage H(1/2 - phi_s/w) minus the geometric
!> one H(1/2 - phi/w) (phi_s, phi: the signed distances at the scaled and the geometric radius).
!> Near another particle j it is weighted by H(1/2 + (phi_j - phi - g)/w), phi_j the geometric
!> signed distance from j: a shell point belongs to k only while it is nearer k's geometric
!> surface than j's by more than g. Two shells therefore end on either side of the surface
!> equidistant from the two bodies and leave a fluid layer of at least g between them, and
!> a shell never comes closer than g to another body; with g the contacts' security zone
!> alpha the voxelised bodies stay as far apart as the contacts keep the geometric ones.
!> Without it, two fibres nearer than 2 (s - 1) R overlap in the solve, their summed
!> coverage bridges the gap with rigid voxels and they move as one body
!> (docs/fluid_coupled_ci.md#fibre-shells-kept-apart). The geometric body keeps weight 1, and
!> H(1 - t) = 1 - H(t) keeps chi twice differentiable in the particle positions. Only voxels
!> within reach of a neighbour (its geometric distance from the voxel centre less than the
!> fibre's plus g + w/2 + 2 half-diagonals: signed distances are 1-Lipschitz) and whose
!> sub-points can fall in the shell (phi < w/2 and phi_geometric > -w/2 within their reach)
!> pay for the neighbours' distances, each of its sub-points only where the scaled and the
!> geometric coverages differ (elsewhere the shell term is exactly 0 whoever owns it), and
!> only for the neighbours that can be the nearest there;
!> the neighbours of each fibre are the periodic images (27 lattice shifts, none across walls)
!> of the particles whose bounding capsules (fold_particles) come that close.
module fold_voxelise
   use, intrinsic :: ieee_arithmetic, only: ieee_is_nan
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_grid, only: grid_t, grid_point
   use fold_particles, only: particle_set_t, FOLD_FIBRE, FOLD_SPHERE, FOLD_SPHEROID, particle_half_segment
   use fold_segment, only: segment_closest
   implicit none
   private

   !> Fibre end shape for voxelisation: flat cylinder (exact, as particle_volume) or capsule
   integer(ip), parameter, public :: FOLD_ENDS_FLAT = 0, FOLD_ENDS_CAPPED = 1

   !> Sparse per-particle voxel lists (CSR) and the summed characteristic function.
   type, public :: voxel_set_t
      !> Number of particles listed
      integer(ip) :: n = 0
      !> Entries of particle k are ptr(k) .. ptr(k+1) - 1
      integer(i8), allocatable :: ptr(:)
      !> Local (1-based) voxel indices (3, capacity)
      integer(ip), allocatable :: ijk(:, :)
      !> Covered fraction of the voxel by this particle
      real(dp), allocatable :: frac(:)
      !> Voxel centre minus particle centre (unwrapped) (3, capacity) [m]
      real(dp), allocatable :: rel(:, :)
      !> Characteristic function on the local slab (nx, n2l, n3l), clipped to [0, 1]
      real(dp), allocatable :: chi(:, :, :)
   end type voxel_set_t

   public :: voxelise, signed_distance

contains

   !> Voxelise every particle of parts on grid; vox keeps its storage between calls.
   subroutine voxelise(grid, parts, subsamples, ends, vox, stat, errmsg, walls, fibre_radius_scale, shell_gap)
      type(grid_t), intent(in) :: grid
      type(particle_set_t), intent(in) :: parts
      !> Sub-samples per voxel edge (1 .. 8)
      integer(ip), intent(in) :: subsamples
      !> Fibre ends: FOLD_ENDS_FLAT or FOLD_ENDS_CAPPED
      integer(ip), intent(in) :: ends
      type(voxel_set_t), intent(inout) :: vox
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> No-slip walls at y = 0 and Ly (Couette cell; default: none): the grid is not
      !> periodic in y, so the part of a particle beyond a wall (a particle that has
      !> crossed it, which the contact step reports) is outside the fluid domain and
      !> is dropped instead of wrapping onto the opposite wall
      logical, intent(in), optional :: walls
      !> Radius of the voxelised fibre over its geometric radius (default 1): a fibre on a
      !> coarse grid turns like a more slender one, so a radius calibrated to the grid can be
      !> given here; spheres and spheroids keep their radius (docs/fluid_coupled_ci.md)
      real(dp), intent(in), optional :: fibre_radius_scale
      !> With fibre_radius_scale > 1: keep the added shells this far [m] from the other
      !> particles' geometric surfaces (see the module's notes); absent or negative (the
      !> default): the shells overlap and their coverages add up
      real(dp), intent(in), optional :: shell_gap

      integer(ip), allocatable :: nb_ptr(:), nb_j(:), cand(:)
      real(dp), allocatable :: nb_x(:, :), dcen(:)
      real(dp) :: gap, r0, hseg0, phig, dmin, own
      integer(ip) :: e, nc, lo_nb, hi_nb
      logical :: apart, near, band
      integer(ip) :: k, dim, ns, s1, s2, s3, is, m(3), lo(3), hi(3), g(3), l(3), i1, i2, i3, nsub
      integer(i8) :: cnt
      real(dp), allocatable :: dr(:, :)
      real(dp) :: xk(3), pk(3), c(3), ext(3), span(3), r(3), w, margin, phi, f, hseg, rk, fscale
      real(dp) :: dsub, slack, sg, ss, row_c(3), row_p(3), row_h, st, tt, dv(3)
      logical :: inside_slab, bounded_y

      bounded_y = .false.
      if (present(walls)) bounded_y = walls
      fscale = 1.0_dp
      if (present(fibre_radius_scale)) fscale = fibre_radius_scale
      stat = FOLD_INPUT_ERROR
      errmsg = ""
      dim = grid%dim
      if (parts%dim /= dim) then
         write (errmsg, '(a,i0,a,i0)') "voxelise: particle set has dim ", parts%dim, ", grid has dim ", dim
         return
      end if
      if (subsamples < 1 .or. subsamples > 8) then
         write (errmsg, '(a,i0)') "voxelise: subsamples must be in 1..8, got ", subsamples
         return
      end if
      if (.not. (fscale > 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "voxelise: fibre_radius_scale must be > 0, got ", fscale
         return
      end if
      gap = -1.0_dp
      if (present(shell_gap)) gap = shell_gap
      if (ieee_is_nan(gap)) then
         errmsg = "voxelise: shell_gap is NaN"
         return
      end if
      if (ends /= FOLD_ENDS_FLAT .and. ends /= FOLD_ENDS_CAPPED) then
         write (errmsg, '(a,i0)') "voxelise: fibre ends must be 0 (flat) or 1 (capped), got ", ends
         return
      end if
      ns = subsamples
      nsub = ns**dim
      allocate (dr(3, nsub))
      is = 0
      do s3 = 1, merge(ns, 1_ip, dim == 3)
         do s2 = 1, ns
            do s1 = 1, ns
               is = is + 1
               dr(:, is) = matmul(grid%A, ([s1, s2, s3] - 0.5_dp)/ns - 0.5_dp)/real(grid%n, dp)
               if (dim == 2) dr(3, is) = 0.0_dp
            end do
         end do
      end do
      w = grid%h/ns
      ! the sub-points lie within dsub of their voxel centre; the signed distances of fibres are exact
      ! Euclidean ones, 1-Lipschitz, so a bound at the centre widened by dsub holds at every sub-point.
      ! slack absorbs the round-off of such a bound (the tests it guards only skip work whose result
      ! is known: chi does not change)
      dsub = maxval(norm2(dr, dim=1))
      slack = 1.0e-9_dp*grid%h
      ! the rows of lattice direction 1: unit direction and the step between voxel centres
      row_p = grid%A(:, 1)/norm2(grid%A(:, 1))
      apart = gap >= 0.0_dp .and. fscale > 1.0_dp
      ! a neighbour counts for the voxels within margin (half-diagonal + w) of the scaled fibre, up to
      ! the gap + w/2 + 2 half-diagonals of the test below
      if (apart) then
         call shell_neighbours(grid, parts, fscale, gap + 3.0_dp*grid%half_diag + 2.0_dp*w, bounded_y, &
                               nb_ptr, nb_j, nb_x)
         allocate (cand(max(1_ip, maxval(nb_ptr(2:) - nb_ptr(:parts%n)))))
         allocate (dcen(size(cand)))
      end if

      if (allocated(vox%chi)) then
         if (any(shape(vox%chi) /= [grid%n(1), grid%nl(2), grid%nl(3)])) deallocate (vox%chi)
      end if
      if (.not. allocated(vox%chi)) allocate (vox%chi(grid%n(1), grid%nl(2), grid%nl(3)))
      vox%chi = 0.0_dp
      if (allocated(vox%ptr)) deallocate (vox%ptr)
      allocate (vox%ptr(parts%n + 1))
      vox%n = parts%n
      call ensure_capacity(vox, 1024_i8)
      cnt = 0
      do k = 1, parts%n
         vox%ptr(k) = cnt + 1
         xk = 0.0_dp
         pk = 0.0_dp
         xk(1:dim) = parts%x(:, k)
         pk(1:dim) = parts%p(:, k)/norm2(parts%p(:, k))
         rk = parts%radius(k)
         if (parts%shape(k) == FOLD_FIBRE) rk = fscale*rk
         hseg = particle_half_segment(parts%shape(k), rk, parts%length(k))
         r0 = parts%radius(k)
         hseg0 = particle_half_segment(parts%shape(k), r0, parts%length(k))
         ext = aabb_half_extent(parts%shape(k), rk, parts%length(k), pk)
         if (dim == 2) ext(3) = 0.0_dp
         ! extent in voxel units along each lattice direction
         span = real(grid%n, dp)*matmul(abs(grid%Ainv), ext)
         if (any(2.0_dp*span(1:dim) > real(grid%n(1:dim), dp) - 2.0_dp)) then
            l(1:1) = maxloc(2.0_dp*span(1:dim) - real(grid%n(1:dim), dp))
            write (errmsg, '(a,i0,a,f0.1,a,i0,a,i0,a)') "voxelise: particle ", k, " spans ", 2.0_dp*span(l(1)), &
               " voxels along lattice direction ", l(1), " of ", grid%n(l(1)), &
               " (a particle must stay clear of its own periodic image: enlarge the cell)"
            return
         end if
         margin = grid%half_diag + w
         if (parts%shape(k) == FOLD_SPHEROID) margin = 2.0_dp*margin
         span = span + real(grid%n, dp)*matmul(abs(grid%Ainv), [margin, margin, margin])
         c = real(grid%n, dp)*matmul(grid%Ainv, xk) - 0.5_dp
         lo = 0
         hi = 0
         lo(1:dim) = floor(c(1:dim) - span(1:dim))
         hi(1:dim) = ceiling(c(1:dim) + span(1:dim))
         do i3 = lo(3), hi(3)
            do i2 = lo(2), hi(2)
               if (bounded_y .and. (i2 < 0 .or. i2 >= grid%n(2))) cycle
               g(2:3) = modulo([i2, i3], grid%n(2:3))
               if (any(g(2:3) < grid%off(2:3) .or. g(2:3) >= grid%off(2:3) + grid%nl(2:3))) cycle
               if (parts%shape(k) == FOLD_FIBRE) then
                  ! a fibre (flat or capped) lies inside the capsule of its axis segment (half-length L/2)
                  ! and radius rk, so no centre of a row farther than rk + margin from that segment
                  ! has phi <= margin
                  row_c = 0.5_dp*(grid_point(grid, [lo(1), i2, i3], 0.5_dp) + grid_point(grid, [hi(1), i2, i3], 0.5_dp)) &
                          - xk
                  row_h = 0.5_dp*real(hi(1) - lo(1), dp)*norm2(grid%A(:, 1))/real(grid%n(1), dp)
                  call segment_closest(row_c, row_p, row_h, pk, 0.5_dp*parts%length(k), st, tt, dv)
                  if (norm2(dv) - rk > margin + slack) cycle
               end if
               do i1 = lo(1), hi(1)
                  m = [i1, i2, i3]
                  g = modulo(m, grid%n)
                  inside_slab = all(g >= grid%off .and. g < grid%off + grid%nl)
                  if (.not. inside_slab) cycle
                  r = grid_point(grid, m, 0.5_dp) - xk
                  phi = signed_distance(parts%shape(k), ends, rk, parts%length(k), hseg, pk, r)
                  if (phi > margin) cycle
                  near = .false.
                  nc = 0
                  if (apart .and. parts%shape(k) == FOLD_FIBRE) then
                     lo_nb = int(nb_ptr(k), ip)
                     hi_nb = int(nb_ptr(k + 1), ip) - 1
                     band = .false.
                     if (hi_nb >= lo_nb) then
                        phig = signed_distance(parts%shape(k), ends, r0, parts%length(k), hseg0, pk, r)
                        ! a neighbour can only claim a sub-point where the shell covers part of it (the
                        ! scaled and geometric coverages differ there: phi < w/2 and phig > -w/2); a voxel
                        ! with no such sub-point has the same chi with or without the neighbours
                        band = phi - dsub < 0.5_dp*w + slack .and. phig + dsub > -0.5_dp*w - slack
                     end if
                     if (band) then
                        do e = lo_nb, hi_nb
                           dcen(e - lo_nb + 1) = nearest_other(parts, ends, nb_j(e:e), nb_x(:, e:e), xk + r)
                        end do
                        dmin = minval(dcen(1:hi_nb - lo_nb + 1))
                        near = dmin - phig < gap + 0.5_dp*w + 2.0_dp*grid%half_diag
                        if (near) then
                           ! a sub-point lies within half_diag of the centre and the distances are
                           ! 1-Lipschitz: only a neighbour within 2 half_diag of the nearest at the
                           ! centre can be the nearest at a sub-point
                           nc = 0
                           do e = lo_nb, hi_nb
                              if (dcen(e - lo_nb + 1) <= dmin + 2.0_dp*grid%half_diag) then
                                 nc = nc + 1
                                 cand(nc) = e
                              end if
                           end do
                        end if
                     end if
                  end if
                  if (phi < -margin .and. .not. near) then
                     f = 1.0_dp
                  else
                     f = 0.0_dp
                     do is = 1, nsub
                        phi = signed_distance(parts%shape(k), ends, rk, parts%length(k), hseg, pk, &
                                              r + dr(:, is))
                        if (near) then
                           ! the geometric body, plus the shell where it is not yielded to a neighbour;
                           ! where the two coverages agree the shell adds exactly 0 whoever owns it
                           phig = signed_distance(parts%shape(k), ends, r0, parts%length(k), hseg0, pk, r + dr(:, is))
                           sg = smooth_step(0.5_dp - phig/w)
                           ss = smooth_step(0.5_dp - phi/w)
                           own = 1.0_dp
                           if (ss /= sg) then
                              dmin = nearest_other(parts, ends, nb_j(cand(1:nc)), nb_x(:, cand(1:nc)), &
                                                   xk + r + dr(:, is))
                              own = smooth_step(0.5_dp + (dmin - phig - gap)/w)
                           end if
                           f = f + sg + own*(ss - sg)
                        else
                           f = f + smooth_step(0.5_dp - phi/w)
                        end if
                     end do
                     f = f/nsub
                     if (f <= 0.0_dp) cycle
                  end if
                  cnt = cnt + 1
                  if (cnt > size(vox%frac, kind=i8)) call ensure_capacity(vox, 2*cnt)
                  l = g - grid%off + 1
                  vox%ijk(:, cnt) = l
                  vox%frac(cnt) = f
                  vox%rel(:, cnt) = r
                  vox%chi(l(1), l(2), l(3)) = vox%chi(l(1), l(2), l(3)) + f
               end do
            end do
         end do
      end do
      vox%ptr(parts%n + 1) = cnt + 1
      ! overlapping particles (a contact failure) must not make chi exceed 1
      vox%chi = min(vox%chi, 1.0_dp)
      stat = FOLD_OK
   end subroutine voxelise

   !> The neighbours whose geometric bodies may claim part of each fibre's added shell: the
   !> periodic images (27 lattice shifts; none across walls) of every other particle whose
   !> bounding capsule comes within reach [m] of the fibre's scaled one (bounding spheres
   !> first, then the capsules' closest axis points, fold_segment). CSR: those
   !> of particle k are nb_j(nb_ptr(k) : nb_ptr(k+1) - 1), nb_x the centres of the images [m].
   !> O(N^2) pair tests, against the solve's O(N_grid log N_grid), once per voxelisation.
   subroutine shell_neighbours(grid, parts, fscale, reach, bounded_y, nb_ptr, nb_j, nb_x)
      type(grid_t), intent(in) :: grid
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: fscale, reach
      logical, intent(in) :: bounded_y
      integer(ip), allocatable, intent(out) :: nb_ptr(:), nb_j(:)
      real(dp), allocatable, intent(out) :: nb_x(:, :)
      integer(ip) :: k, j, a, b, c, cnt, dim
      real(dp) :: xk(3), xj(3), d(3), bk, bj, pk(3), pj(3), hk, hj, sk, tj_, dvec(3)
      integer(ip), allocatable :: tj(:)
      real(dp), allocatable :: tx(:, :)
      dim = parts%dim
      allocate (nb_ptr(parts%n + 1), nb_j(max(16_ip, 8_ip*parts%n)), nb_x(3, max(16_ip, 8_ip*parts%n)))
      cnt = 0
      do k = 1, parts%n
         nb_ptr(k) = cnt + 1
         if (parts%shape(k) /= FOLD_FIBRE) cycle
         xk = 0.0_dp
         xk(1:dim) = parts%x(:, k)
         pk = 0.0_dp
         pk(1:dim) = parts%p(:, k)/norm2(parts%p(:, k))
         hk = particle_half_segment(parts%shape(k), fscale*parts%radius(k), parts%length(k))
         bk = hk + fscale*parts%radius(k)
         do j = 1, parts%n
            if (j == k) cycle
            xj = 0.0_dp
            xj(1:dim) = parts%x(:, j)
            pj = 0.0_dp
            pj(1:dim) = parts%p(:, j)/norm2(parts%p(:, j))
            hj = particle_half_segment(parts%shape(j), parts%radius(j), parts%length(j))
            bj = hj + parts%radius(j)
            do c = merge(-1, 0, dim == 3), merge(1, 0, dim == 3)
               do b = merge(0, -1, bounded_y), merge(0, 1, bounded_y)
                  do a = -1, 1
                     d = xj + matmul(grid%A, real([a, b, c], dp)) - xk
                     if (norm2(d) > bk + bj + reach) cycle
                     ! the bounding capsules (fold_particles), which contain the bodies, within reach
                     call segment_closest(-d, pk, hk, pj, hj, sk, tj_, dvec)
                     if (norm2(dvec) > fscale*parts%radius(k) + parts%radius(j) + reach) cycle
                     cnt = cnt + 1
                     if (cnt > size(nb_j)) then
                        allocate (tj(2*size(nb_j)), tx(3, 2*size(nb_j)))
                        tj(1:cnt - 1) = nb_j(1:cnt - 1)
                        tx(:, 1:cnt - 1) = nb_x(:, 1:cnt - 1)
                        call move_alloc(tj, nb_j)
                        call move_alloc(tx, nb_x)
                     end if
                     nb_j(cnt) = j
                     nb_x(:, cnt) = xk + d
                  end do
               end do
            end do
         end do
      end do
      nb_ptr(parts%n + 1) = cnt + 1
   end subroutine shell_neighbours

   !> The smallest geometric signed distance [m] of the point x from the particles js whose
   !> (image) centres are xs.
   pure function nearest_other(parts, ends, js, xs, x) result(dmin)
      type(particle_set_t), intent(in) :: parts
      integer(ip), intent(in) :: ends, js(:)
      real(dp), intent(in) :: xs(:, :), x(3)
      real(dp) :: dmin
      integer(ip) :: e, j, dim
      real(dp) :: pj(3)
      dim = parts%dim
      dmin = huge(1.0_dp)
      do e = 1, size(js)
         j = js(e)
         pj = 0.0_dp
         pj(1:dim) = parts%p(:, j)/norm2(parts%p(:, j))
         dmin = min(dmin, signed_distance(parts%shape(j), ends, parts%radius(j), parts%length(j), &
                                          particle_half_segment(parts%shape(j), parts%radius(j), parts%length(j)), &
                                          pj, x - xs(:, e)))
      end do
   end function nearest_other

   !> Signed distance [m] from the particle surface of a point at r = x - centre
   !> (negative inside). Spheroid: first-order estimate, exact on the surface.
   pure function signed_distance(shape, ends, radius, length, hseg, p, r) result(phi)
      integer(ip), intent(in) :: shape, ends
      real(dp), intent(in) :: radius, length, hseg, p(3), r(3)
      real(dp) :: phi
      real(dp) :: z, rho2, a, b, q, gq, t
      select case (shape)
      case (FOLD_SPHERE)
         phi = norm2(r) - radius
      case (FOLD_FIBRE)
         z = dot_product(r, p)
         if (ends == FOLD_ENDS_CAPPED) then
            t = max(-hseg, min(hseg, z))
            phi = norm2(r - t*p) - radius
         else
            a = abs(z) - 0.5_dp*length
            b = sqrt(max(0.0_dp, dot_product(r, r) - z*z)) - radius
            phi = min(max(a, b), 0.0_dp) + sqrt(max(a, 0.0_dp)**2 + max(b, 0.0_dp)**2)
         end if
      case default
         a = 0.5_dp*length
         b = radius
         z = dot_product(r, p)
         rho2 = max(0.0_dp, dot_product(r, r) - z*z)
         q = sqrt(z*z/(a*a) + rho2/(b*b))
         if (q < 1.0e-12_dp) then
            phi = -b
         else
            gq = sqrt(z*z/a**4 + rho2/b**4)/q
            phi = (q - 1.0_dp)/gq
         end if
      end select
   end function signed_distance

   !> C2 step 10t^3 - 15t^4 + 6t^5 clamped to [0, 1]; H(1-t) = 1 - H(t).
   pure function smooth_step(t) result(h)
      real(dp), intent(in) :: t
      real(dp) :: h, c
      c = min(1.0_dp, max(0.0_dp, t))
      h = c*c*c*(10.0_dp + c*(-15.0_dp + 6.0_dp*c))
   end function smooth_step

   !> Half extents of the axis-aligned bounding box of a particle of axis p [m].
   pure function aabb_half_extent(shape, radius, length, p) result(e)
      integer(ip), intent(in) :: shape
      real(dp), intent(in) :: radius, length, p(3)
      real(dp) :: e(3)
      select case (shape)
      case (FOLD_SPHERE)
         e = radius
      case (FOLD_FIBRE)
         ! capsule bound (contains the flat cylinder too)
         e = 0.5_dp*length*abs(p) + radius
      case default
         e = sqrt((0.5_dp*length*p)**2 + radius**2*(1.0_dp - p**2))
      end select
   end function aabb_half_extent

   subroutine ensure_capacity(vox, need)
      type(voxel_set_t), intent(inout) :: vox
      integer(i8), intent(in) :: need
      integer(ip), allocatable :: ijk(:, :)
      real(dp), allocatable :: frac(:), rel(:, :)
      integer(i8) :: old
      if (allocated(vox%frac)) then
         old = size(vox%frac, kind=i8)
         if (old >= need) return
         allocate (ijk(3, need), frac(need), rel(3, need))
         ijk(:, 1:old) = vox%ijk
         frac(1:old) = vox%frac
         rel(:, 1:old) = vox%rel
         call move_alloc(ijk, vox%ijk)
         call move_alloc(frac, vox%frac)
         call move_alloc(rel, vox%rel)
      else
         allocate (vox%ijk(3, need), vox%frac(need), vox%rel(3, need))
      end if
   end subroutine ensure_capacity

end module fold_voxelise
