!> Closest points between two segments, and the capsule gap built on it.
!>
!> Segment k is { c_k + s p_k : s in [-h_k, h_k] } with unit axis p_k (h_k = 0 is a
!> point: a sphere's centre). We minimise the convex quadratic
!>     f(s,t) = |r + s p1 - t p2|^2,  r = c1 - c2,
!> over the rectangle [-h1,h1] x [-h2,h2]. Its unconstrained minimiser is the seed's
!> interior formula (Laure, Megally & Coupez; docs/physics.md#fibre-collisions):
!>     s* = (b e - d)/(1 - b^2),  t* = (e - b d)/(1 - b^2),  b = p1.p2, d = p1.r, e = p2.r;
!> f is convex, so on the rectangle its minimum is either that interior point or lies
!> on an edge, i.e. an end point of one segment against the other segment, where the
!> 1-D minimiser is a clamped projection (Ericson 2005, Real-Time Collision Detection,
!> section 5.1.9). When the axes are parallel (1 - b^2 <= eps_parallel) every s of the
!> overlap of the two projections is optimal; we take the middle of the overlap, so the
!> contact point (and hence the torque of a contact force) is symmetric.
!>
!> Shapes as capsules (see fold_particles): fibre = capsule over its axis (contains the
!> cylinder), sphere = capsule of zero length (exact), spheroid = bounding capsule of
!> half-length a - b (contains the spheroid, exact at the tips and the equator; the
!> gap of two spheroids is therefore a lower bound of the true gap).
module fold_segment
   use fold_kinds, only: dp
   implicit none
   private

   !> 1 - (p1.p2)^2 below which two axes are treated as parallel [-]
   real(dp), parameter, public :: eps_parallel = 1.0e-12_dp

   public :: segment_closest, capsule_contact

contains

   pure function clamp(x, lo, hi) result(y)
      real(dp), intent(in) :: x, lo, hi
      real(dp) :: y
      y = min(max(x, lo), hi)
   end function clamp

   !> Closest points of two segments: parameters s (on 1), t (on 2) and the vector
   !> dvec = (c1 + s p1) - (c2 + t p2) from the point on 2 to the point on 1.
   !> r = c1 - c2 is given (already reduced to its minimum image by the caller).
   !> Candidates: the interior stationary point (if it lies in the rectangle), the four
   !> edges (an end point of one segment against the other segment: a clamped 1-D
   !> projection, exact), and for parallel axes the middle of the overlap. The
   !> candidate with the smallest actual |dvec| wins, so ill-conditioning of the
   !> interior formula for nearly parallel axes cannot give a wrong answer.
   pure subroutine segment_closest(r, p1, h1, p2, h2, s, t, dvec)
      !> Centre displacement c1 - c2 [m]
      real(dp), intent(in) :: r(:)
      !> Unit axis of segment 1 [-]
      real(dp), intent(in) :: p1(:)
      !> Half-length of segment 1 (>= 0) [m]
      real(dp), intent(in) :: h1
      !> Unit axis of segment 2 [-]
      real(dp), intent(in) :: p2(:)
      !> Half-length of segment 2 (>= 0) [m]
      real(dp), intent(in) :: h2
      !> Arc-length parameter of the closest point on 1, in [-h1, h1] [m]
      real(dp), intent(out) :: s
      !> Arc-length parameter of the closest point on 2, in [-h2, h2] [m]
      real(dp), intent(out) :: t
      !> Closest-point vector (point on 1) - (point on 2) [m]
      real(dp), intent(out) :: dvec(size(r))

      real(dp) :: b, d, e, denom, lo, hi, half, best, sc, tc, tie, dist
      real(dp) :: cs(7), ct(7), cm(7)
      integer :: k, nc

      b = dot_product(p1, p2)
      d = dot_product(p1, r)
      e = dot_product(p2, r)
      denom = 1.0_dp - b*b
      tie = 8.0_dp*epsilon(1.0_dp)*(norm2(r) + h1 + h2)
      nc = 0
      if (denom <= eps_parallel .and. h1 > 0.0_dp .and. h2 > 0.0_dp) then
         ! parallel: segment 2 projects on line 1 onto s in [-d - h2|b|, -d + h2|b|];
         ! the middle of the overlap keeps the contact point symmetric
         half = h2*abs(b)
         lo = max(-h1, -d - half)
         hi = min(h1, -d + half)
         if (lo <= hi) then
            nc = nc + 1
            cs(nc) = 0.5_dp*(lo + hi)
            ct(nc) = clamp(e + cs(nc)*b, -h2, h2)
            cm(nc) = 0.0_dp
         end if
      end if
      if (denom > 0.0_dp) then
         ! interior stationary point (ill-conditioned when nearly parallel, but judged
         ! by its actual distance like every other candidate)
         sc = (b*e - d)/denom
         tc = (e - b*d)/denom
         if (abs(sc) <= h1 .and. abs(tc) <= h2) then
            nc = nc + 1
            cs(nc) = sc
            ct(nc) = tc
            cm(nc) = tie
         end if
      end if
      do k = -1, 1, 2
         ! end point s = +/-h1 of segment 1 against segment 2
         nc = nc + 1
         cs(nc) = k*h1
         ct(nc) = clamp(e + cs(nc)*b, -h2, h2)
         cm(nc) = tie
         ! end point t = +/-h2 of segment 2 against segment 1
         nc = nc + 1
         ct(nc) = k*h2
         cs(nc) = clamp(ct(nc)*b - d, -h1, h1)
         cm(nc) = tie
      end do
      ! the overlap middle (parallel axes) is replaced only by a clearly closer candidate
      best = huge(1.0_dp)
      s = 0.0_dp
      t = 0.0_dp
      do k = 1, nc
         dist = norm2(r + cs(k)*p1 - ct(k)*p2)
         if (dist < best - cm(k)) then
            best = dist
            s = cs(k)
            t = ct(k)
         end if
      end do
      dvec = r + s*p1 - t*p2
   end subroutine segment_closest

   !> Contact geometry of two capsules (radii R1, R2, half-segments h1, h2):
   !> surface distance dist = |dvec| - R1 - R2, the unit normal n pointing from 2 to 1,
   !> and the arms s, t of the closest axis points from the centres.
   !> When the axes touch or cross (|dvec| ~ 0) the normal is taken along p1 x p2 (3-D),
   !> or perpendicular to p1 (2-D), with the sign that points from c2 towards c1;
   !> for coincident sphere centres n = e_x.
   pure subroutine capsule_contact(r, p1, h1, rad1, p2, h2, rad2, dist, n, s, t)
      !> Centre displacement c1 - c2 (minimum image) [m]
      real(dp), intent(in) :: r(:)
      real(dp), intent(in) :: p1(:)
      real(dp), intent(in) :: h1, rad1
      real(dp), intent(in) :: p2(:)
      real(dp), intent(in) :: h2, rad2
      !> Surface-to-surface distance (negative when overlapping) [m]
      real(dp), intent(out) :: dist
      !> Unit contact normal, from body 2 to body 1 [-]
      real(dp), intent(out) :: n(size(r))
      !> Closest axis-point parameters on 1 and 2 [m]
      real(dp), intent(out) :: s, t

      ! fixed-size local (used as dvec(1:dim)): an automatic array would be a heap
      ! allocation per call, and this runs for every candidate pair of every list build
      real(dp) :: dvec(3), dn, scale, c(3), cn
      integer :: dim

      dim = size(r)
      call segment_closest(r, p1, h1, p2, h2, s, t, dvec(1:dim))
      dn = norm2(dvec(1:dim))
      dist = dn - rad1 - rad2
      scale = max(h1 + h2 + rad1 + rad2, tiny(1.0_dp))
      if (dn > 1.0e-14_dp*scale) then
         n = dvec(1:dim)/dn
         return
      end if
      ! degenerate: axes intersect
      if (dim == 3) then
         c(1) = p1(2)*p2(3) - p1(3)*p2(2)
         c(2) = p1(3)*p2(1) - p1(1)*p2(3)
         c(3) = p1(1)*p2(2) - p1(2)*p2(1)
         cn = norm2(c)
         if (cn <= 1.0e-12_dp .or. h1 <= 0.0_dp .or. h2 <= 0.0_dp) then
            ! any direction perpendicular to p1 (or e_x for points)
            if (h1 <= 0.0_dp .and. h2 <= 0.0_dp) then
               c = [1.0_dp, 0.0_dp, 0.0_dp]
            else if (h1 > 0.0_dp) then
               c = perpendicular3(p1)
            else
               c = perpendicular3(p2)
            end if
            cn = 1.0_dp
         end if
         n = c/cn
      else
         if (h1 > 0.0_dp) then
            n = [-p1(2), p1(1)]
         else if (h2 > 0.0_dp) then
            n = [-p2(2), p2(1)]
         else
            n = [1.0_dp, 0.0_dp]
         end if
      end if
      if (dot_product(n, r) < 0.0_dp) n = -n
   end subroutine capsule_contact

   !> A unit vector perpendicular to the unit vector p.
   pure function perpendicular3(p) result(q)
      real(dp), intent(in) :: p(3)
      real(dp) :: q(3)
      if (abs(p(1)) < 0.9_dp) then
         q = [0.0_dp, p(3), -p(2)] ! -(e_x x p)
      else
         q = [-p(3), 0.0_dp, p(1)] ! -(e_y x p)
      end if
      q = q/norm2(q)
   end function perpendicular3

end module fold_segment
