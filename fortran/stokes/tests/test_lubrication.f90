!> fold_lubrication against the closed forms of its module header.
!>
!> * two equal spheres approaching along their line of centres: delta v = -c w0/(M + 2c) n
!>   exactly (M = 6 pi eta R, c = (3/2) pi eta R^2 (1/h - 1/h_c), written out here, not
!>   taken from the module), opposing the approach; the log-log slope of |delta v| against
!>   the gap, and of the recovered pair coefficient, lies between the extreme local
!>   exponents of that closed form over the fitted range;
!> * tangential relative motion, a pair beyond h_c, a non-sphere: untouched (exactly 0);
!> * a pair across the sheared (Lees-Edwards) face moving with the imposed flow gets the
!>   same correction as the same pair inside the cell;
!> * three spheres in a row: the simultaneous solve satisfies (M + L) dv = b (matrix
!>   written out densely here) within the round-off bound, agrees with Gaussian
!>   elimination, and differs from pair-by-pair corrections in sequence.
!> Tolerances: the solver's residual bound tau (64 eps (a |dv| + |b|)) over the smallest
!> eigenvalue M of M + L bounds the error of dv; the closed form itself is evaluated to a
!> few eps relative.
program test_lubrication
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_init, cell_set_time, cell_mean_velocity, cell_min_image
   use fold_lubrication, only: lubrication_stats_t, lubrication_correct, lubrication_coefficient, &
                               lubrication_force, lubrication_threshold, lubrication_gap_floor
   use stokes_test_check, only: check, check_start, check_passed
   implicit none
   real(dp), parameter :: pi = acos(-1.0_dp), eps = epsilon(1.0_dp)
   real(dp), parameter :: R = 1.0e-4_dp, eta = 2.0e-3_dp, U = 3.0e-5_dp
   integer :: failures

   failures = 0
   call check_start("test_lubrication", .true.)
   call two_spheres_closed_form(failures)
   call exponent_fits(failures)
   call untouched(failures)
   call lees_edwards_image(failures)
   call three_in_a_row(failures)
   call one_formula(failures)
   if (.not. check_passed(failures)) error stop 1

contains

   !> A 3-D periodic cell of side L (at rest, or in simple shear at time t).
   function make_cell(L, gdot, t) result(cell)
      real(dp), intent(in) :: L, gdot, t
      type(cell_t) :: cell
      real(dp) :: G(3, 3)
      integer :: stat
      character(len=msg_len) :: errmsg
      G = 0.0_dp
      G(1, 2) = gdot
      call cell_init(cell, 3_ip, [L, L, L], .false., G, stat, errmsg)
      if (stat /= FOLD_OK) error stop "make_cell: "//trim(errmsg)
      call cell_set_time(cell, t)
   end function make_cell

   !> Two equal spheres on the x axis, gap h, approaching at 2U: returns dv(:, 1) and stats.
   subroutine approach(h, h_c, gap_min, dv, st)
      real(dp), intent(in) :: h, h_c, gap_min
      real(dp), intent(out) :: dv(3, 2)
      type(lubrication_stats_t), intent(out) :: st
      type(cell_t) :: cell
      real(dp) :: x(3, 2), v0(3, 2), L
      integer :: stat
      character(len=msg_len) :: errmsg
      L = 5.0_dp*(2.0_dp*R + h_c)
      cell = make_cell(L, 0.0_dp, 0.0_dp)
      x(:, 1) = [0.5_dp*L - R - 0.5_dp*h, 0.5_dp*L, 0.5_dp*L]
      x(:, 2) = [0.5_dp*L + R + 0.5_dp*h, 0.5_dp*L, 0.5_dp*L]
      v0(:, 1) = [U, 0.0_dp, 0.0_dp]
      v0(:, 2) = [-U, 0.0_dp, 0.0_dp]
      call lubrication_correct(cell, x, [R, R], [.true., .true.], v0, eta, h_c, gap_min, dv, st, stat, errmsg)
      if (stat /= FOLD_OK) error stop "approach: "//trim(errmsg)
   end subroutine approach

   !> Closed form of the two-sphere correction of sphere 1 (x component), written out.
   pure function closed_form(h, h_c) result(dv1)
      real(dp), intent(in) :: h, h_c
      real(dp) :: dv1, c, m
      m = 6.0_dp*pi*eta*R
      c = 1.5_dp*pi*R**2*eta*(1.0_dp/h - 1.0_dp/h_c)
      ! n_12 = -e_x, w0 = (v0_1 - v0_2).n_12 = -2U: dv_1 = -c w0/(M + 2c) n_12 = -2U c/(M + 2c) e_x
      dv1 = -2.0_dp*U*c/(m + 2.0_dp*c)
   end function closed_form

   subroutine two_spheres_closed_form(failures)
      integer, intent(inout) :: failures
      real(dp) :: dv(3, 2), h_c, h, m, err, tol
      type(lubrication_stats_t) :: st
      integer :: k
      character(len=160) :: what
      h_c = lubrication_threshold(R/2.0_dp)  ! 4 voxels per diameter
      m = 6.0_dp*pi*eta*R
      do k = 0, 4
         h = h_c*10.0_dp**(-0.5_dp*k - 0.3_dp)
         call approach(h, h_c, 1.0e-6_dp*h_c, dv, st)
         err = abs(dv(1, 1) - closed_form(h, h_c))
         ! solver error <= tau / M; closed form to 16 eps relative
         tol = st%residual_bound/m + 16.0_dp*eps*abs(closed_form(h, h_c))
         write (what, '(a,es9.2,a,es11.4,a,es11.4,a,es9.2)') "two spheres, gap/h_c ", h/h_c, ": dv ", dv(1, 1), &
            " vs closed form ", closed_form(h, h_c), ", tol ", tol
         print '(a)', trim(what)
         call check(err <= tol, trim(what), failures)
         call check(dv(1, 1) < 0.0_dp .and. dv(1, 2) > 0.0_dp, "correction opposes the approach", failures)
         call check(all(dv(2:3, :) == 0.0_dp), "no transverse correction", failures)
         call check(abs(dv(1, 1) + dv(1, 2)) <= 4.0_dp*eps*abs(dv(1, 1)) + 2.0_dp*st%residual_bound/m, &
                    "equal and opposite corrections", failures)
         call check(st%pairs == 1 .and. st%residual <= st%residual_bound, "one pair, residual within bound", failures)
      end do
   end subroutine two_spheres_closed_form

   !> Least-squares slope of log(y) against log(x).
   pure function slope(x, y) result(s)
      real(dp), intent(in) :: x(:), y(:)
      real(dp) :: s, lx(size(x)), ly(size(y))
      lx = log(x)
      ly = log(y)
      s = sum((lx - sum(lx)/size(lx))*(ly - sum(ly)/size(ly)))/sum((lx - sum(lx)/size(lx))**2)
   end function slope

   !> (a) Weak coupling (c << M, gaps of tens of radii, h_c far away): |dv| ~ 1/gap, local
   !> exponent p(h) = -(h_c/(h_c - h)) M/(M + 2c). (b) Near contact (h << R, h << h_c): |dv|
   !> saturates at U (the pair stops approaching), while the coefficient recovered from the
   !> solution, c_eff = M |dv_1| / |w0 + (dv_1 - dv_2).n|, has local exponent -h_c/(h_c - h).
   !> The least-squares slope over equally spaced log h is a positive average of local
   !> exponents, so it lies within their extremes (plus a round-off margin of 1e-6).
   subroutine exponent_fits(failures)
      integer, intent(inout) :: failures
      integer, parameter :: nh = 9
      real(dp) :: h(nh), y(nh), ceff(nh), dv(3, 2), h_c, m, c, pmin, pmax, p, s, wrel
      type(lubrication_stats_t) :: st
      integer :: k
      character(len=160) :: what
      m = 6.0_dp*pi*eta*R
      ! (a)
      h_c = 1.0e6_dp*R
      pmin = huge(1.0_dp)
      pmax = -huge(1.0_dp)
      do k = 1, nh
         h(k) = 30.0_dp*R*10.0_dp**((k - 1)/real(nh - 1, dp))
         call approach(h(k), h_c, 1.0e-3_dp*R, dv, st)
         y(k) = abs(dv(1, 1))
         c = 1.5_dp*pi*R**2*eta*(1.0_dp/h(k) - 1.0_dp/h_c)
         p = -(h_c/(h_c - h(k)))*m/(m + 2.0_dp*c)
         pmin = min(pmin, p)
         pmax = max(pmax, p)
      end do
      s = slope(h, y)
      write (what, '(a,f9.5,a,f9.5,a,f9.5,a)') "weak coupling, gap 30-300 R: exponent of |dv| ", s, &
         " within [", pmin, ", ", pmax, "]"
      print '(a)', trim(what)
      call check(s >= pmin - 1.0e-6_dp .and. s <= pmax + 1.0e-6_dp, trim(what), failures)
      ! (b)
      h_c = lubrication_threshold(R/2.0_dp)
      pmin = huge(1.0_dp)
      pmax = -huge(1.0_dp)
      do k = 1, nh
         h(k) = 1.0e-4_dp*h_c*10.0_dp**(2.0_dp*(k - 1)/real(nh - 1, dp))
         call approach(h(k), h_c, 1.0e-7_dp*h_c, dv, st)
         y(k) = abs(dv(1, 1))
         ! corrected approach rate (n_12 = -e_x): w0 + (dv_1 - dv_2).n
         wrel = -2.0_dp*U - (dv(1, 1) - dv(1, 2))
         ceff(k) = m*abs(dv(1, 1))/abs(wrel)
         p = -h_c/(h_c - h(k))
         pmin = min(pmin, p)
         pmax = max(pmax, p)
      end do
      s = slope(h, ceff)
      write (what, '(a,f9.5,a,f9.5,a,f9.5,a)') "near contact, gap 1e-4-1e-2 h_c: exponent of the pair coefficient ", &
         s, " within [", pmin, ", ", pmax, "]"
      print '(a)', trim(what)
      call check(s >= pmin - 1.0e-6_dp .and. s <= pmax + 1.0e-6_dp, trim(what), failures)
      write (what, '(a,es10.3,a,es10.3,a)') "near contact: |dv|/U from ", y(nh)/U, " (gap 1e-2 h_c) to ", &
         y(1)/U, " (gap 1e-4 h_c), limit 1"
      print '(a)', trim(what)
      call check(y(1) < U .and. y(1) > y(nh), "near contact: the correction saturates below U", failures)
   end subroutine exponent_fits

   !> Tangential motion, a pair beyond h_c, and a non-sphere next to a sphere: dv = 0 exactly.
   subroutine untouched(failures)
      integer, intent(inout) :: failures
      type(cell_t) :: cell
      type(lubrication_stats_t) :: st
      real(dp) :: x(3, 3), v0(3, 3), dv(3, 3), h_c, L, h
      integer :: stat
      character(len=msg_len) :: errmsg
      h_c = lubrication_threshold(R/2.0_dp)
      L = 10.0_dp*(2.0_dp*R + h_c)
      cell = make_cell(L, 0.0_dp, 0.0_dp)
      h = 0.1_dp*h_c
      x(:, 1) = [0.3_dp*L, 0.5_dp*L, 0.5_dp*L]
      x(:, 2) = x(:, 1) + [2.0_dp*R + h, 0.0_dp, 0.0_dp]
      x(:, 3) = [0.8_dp*L, 0.5_dp*L, 0.5_dp*L]
      ! sliding past each other (relative velocity along y and z, normal along x)
      v0(:, 1) = [0.0_dp, U, -U]
      v0(:, 2) = [0.0_dp, -U, 0.5_dp*U]
      v0(:, 3) = [U, 0.0_dp, 0.0_dp]
      call lubrication_correct(cell, x, [R, R, R], [.true., .true., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv, st, &
                               stat, errmsg)
      call check(stat == FOLD_OK .and. st%pairs == 1 .and. all(dv == 0.0_dp), "tangential motion not corrected", &
                 failures)
      ! beyond h_c (approaching): no pair
      x(:, 2) = x(:, 1) + [2.0_dp*R + 1.01_dp*h_c, 0.0_dp, 0.0_dp]
      v0(:, 1) = [U, 0.0_dp, 0.0_dp]
      v0(:, 2) = [-U, 0.0_dp, 0.0_dp]
      call lubrication_correct(cell, x, [R, R, R], [.true., .true., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv, st, &
                               stat, errmsg)
      call check(stat == FOLD_OK .and. st%pairs == 0 .and. all(dv == 0.0_dp), "pair beyond h_c untouched", failures)
      ! a close approaching pair with a non-sphere: untouched; the far sphere 3 too
      x(:, 2) = x(:, 1) + [2.0_dp*R + h, 0.0_dp, 0.0_dp]
      call lubrication_correct(cell, x, [R, R, R], [.true., .false., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv, st, &
                               stat, errmsg)
      call check(stat == FOLD_OK .and. st%pairs == 0 .and. all(dv == 0.0_dp), "non-sphere partner untouched", failures)
      call lubrication_correct(cell, x, [R, R, R], [.true., .true., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv, st, &
                               stat, errmsg)
      call check(stat == FOLD_OK .and. st%pairs == 1 .and. dv(1, 1) < 0.0_dp .and. all(dv(:, 3) == 0.0_dp), &
                 "sphere outside every pair untouched", failures)
   end subroutine untouched

   !> Sheared cell at a time with a Lees-Edwards offset; both spheres move with the imposed
   !> flow u_mean(x). The pair straddling the y faces (image of 2 below 1) must get the
   !> correction of the same relative configuration placed inside the cell.
   subroutine lees_edwards_image(failures)
      integer, intent(inout) :: failures
      type(cell_t) :: cell
      type(lubrication_stats_t) :: st1, st2
      real(dp) :: x(3, 2), v0(3, 2), dv1(3, 2), dv2(3, 2), h_c, L, d(3), gdot, tol
      integer :: stat
      character(len=msg_len) :: errmsg
      character(len=160) :: what
      h_c = lubrication_threshold(R/2.0_dp)
      L = 10.0_dp*(2.0_dp*R + h_c)
      gdot = 7.0_dp
      cell = make_cell(L, gdot, 0.123_dp/gdot)
      ! relative position: a gap 0.2 h_c along a direction in the compressional quadrant
      d = [-1.0_dp, 1.0_dp, 0.3_dp]
      d = d/norm2(d)*(2.0_dp*R + 0.2_dp*h_c)
      ! inside the cell
      x(:, 2) = [0.5_dp*L, 0.4_dp*L, 0.5_dp*L]
      x(:, 1) = x(:, 2) + d
      v0(:, 1) = cell_mean_velocity(cell, x(:, 1))
      v0(:, 2) = cell_mean_velocity(cell, x(:, 2))
      call lubrication_correct(cell, x, [R, R], [.true., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv1, st1, stat, errmsg)
      call check(stat == FOLD_OK .and. st1%pairs == 1, "inside pair found", failures)
      ! across the faces: sphere 1 just above y = 0, sphere 2 at the image position near y = L
      x(:, 1) = [0.3_dp*L, 0.2_dp*d(2), 0.5_dp*L]
      x(:, 2) = x(:, 1) - d
      ! the image of 2 one lattice vector a2 = (s, L, 0) up: back in the cell
      x(:, 2) = x(:, 2) + [cell%shear_offset, L, 0.0_dp]
      x(1, 2) = modulo(x(1, 2), L)
      v0(:, 1) = cell_mean_velocity(cell, x(:, 1))
      v0(:, 2) = cell_mean_velocity(cell, x(:, 2))
      call lubrication_correct(cell, x, [R, R], [.true., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv2, st2, stat, errmsg)
      ! solver bounds, plus the round-off of coordinates of size L in a gap of 0.2 h_c (the
      ! coefficient goes like 1/gap) and in the mean-flow difference G (x_a - x_b)
      tol = (st1%residual_bound + st2%residual_bound)/(6.0_dp*pi*eta*R) + &
            64.0_dp*eps*(L/(0.2_dp*h_c))*maxval(abs(dv1))
      write (what, '(a,es11.4,a,es11.4,a,es9.2,a,es9.2)') "Lees-Edwards pair: dv_x ", dv2(1, 1), " vs inside ", &
         dv1(1, 1), ", |diff| ", maxval(abs(dv2 - dv1)), ", tol ", tol
      print '(a)', trim(what)
      call check(stat == FOLD_OK .and. st2%pairs == 1, "Lees-Edwards pair found", failures)
      call check(maxval(abs(dv2 - dv1)) <= tol .and. abs(dv1(1, 1)) > 0.0_dp, trim(what), failures)
   end subroutine lees_edwards_image

   !> Three equal spheres on the x axis with gaps h1, h2 and different velocities.
   subroutine three_in_a_row(failures)
      integer, intent(inout) :: failures
      type(cell_t) :: cell
      type(lubrication_stats_t) :: st
      real(dp) :: x(3, 3), v0(3, 3), dv(3, 3), h_c, L, gaps(2), c(2), m, a(9, 9), b(9), res(9), xd(9), seq(3, 3)
      real(dp) :: n(3), tol, kappa, diff
      integer :: stat, k, i, j
      character(len=msg_len) :: errmsg
      character(len=200) :: what
      h_c = lubrication_threshold(R/2.0_dp)
      L = 10.0_dp*(2.0_dp*R + h_c)
      cell = make_cell(L, 0.0_dp, 0.0_dp)
      gaps = [0.05_dp*h_c, 0.2_dp*h_c]
      x(:, 1) = [0.3_dp*L, 0.5_dp*L, 0.5_dp*L]
      x(:, 2) = x(:, 1) + [2.0_dp*R + gaps(1), 0.0_dp, 0.0_dp]
      x(:, 3) = x(:, 2) + [2.0_dp*R + gaps(2), 0.0_dp, 0.0_dp]
      v0(:, 1) = [U, 0.2_dp*U, 0.0_dp]
      v0(:, 2) = [-0.5_dp*U, 0.0_dp, 0.1_dp*U]
      v0(:, 3) = [-U, 0.0_dp, 0.0_dp]
      call lubrication_correct(cell, x, [R, R, R], [.true., .true., .true.], v0, eta, h_c, 1.0e-3_dp*h_c, dv, st, &
                               stat, errmsg)
      call check(stat == FOLD_OK .and. st%pairs == 2, "three in a row: two pairs", failures)
      ! dense M + L and b, written out: pair (1,2) and (2,3), n from the right sphere to the left = -e_x
      m = 6.0_dp*pi*eta*R
      c = 1.5_dp*pi*R**2*eta*(1.0_dp/gaps - 1.0_dp/h_c)
      n = [-1.0_dp, 0.0_dp, 0.0_dp]
      a = 0.0_dp
      do k = 1, 9
         a(k, k) = m
      end do
      b = 0.0_dp
      do k = 1, 2
         do i = 1, 3
            do j = 1, 3
               a(3*(k - 1) + i, 3*(k - 1) + j) = a(3*(k - 1) + i, 3*(k - 1) + j) + c(k)*n(i)*n(j)
               a(3*k + i, 3*k + j) = a(3*k + i, 3*k + j) + c(k)*n(i)*n(j)
               a(3*(k - 1) + i, 3*k + j) = a(3*(k - 1) + i, 3*k + j) - c(k)*n(i)*n(j)
               a(3*k + i, 3*(k - 1) + j) = a(3*k + i, 3*(k - 1) + j) - c(k)*n(i)*n(j)
            end do
            b(3*(k - 1) + i) = b(3*(k - 1) + i) - c(k)*dot_product(v0(:, k) - v0(:, k + 1), n)*n(i)
            b(3*k + i) = b(3*k + i) + c(k)*dot_product(v0(:, k) - v0(:, k + 1), n)*n(i)
         end do
      end do
      res = b - matmul(a, reshape(dv, [9]))
      write (what, '(a,es10.3,a,es10.3,a)') "three in a row: residual ", norm2(res), " N within the bound ", &
         st%residual_bound, " N"
      print '(a)', trim(what)
      call check(norm2(res) <= st%residual_bound, trim(what), failures)
      ! Gaussian elimination (no pivoting needed: SPD); error <= kappa 9 eps |x| beside tau/M
      xd = gauss(a, b)
      kappa = (m + 4.0_dp*maxval(c))/m
      tol = st%residual_bound/m + 16.0_dp*kappa*9.0_dp*eps*norm2(xd)
      write (what, '(a,es10.3,a,es10.3)') "three in a row: |dv - dense solve| ", norm2(reshape(dv, [9]) - xd), &
         " <= ", tol
      print '(a)', trim(what)
      call check(norm2(reshape(dv, [9]) - xd) <= tol, trim(what), failures)
      ! pair by pair in sequence, each from the velocities the previous pair left
      seq = v0
      do k = 1, 2
         seq(:, k:k + 1) = seq(:, k:k + 1) + pair_correction(seq(:, k), seq(:, k + 1), c(k), m, n)
      end do
      seq = seq - v0
      diff = maxval(abs(seq - dv))
      write (what, '(a,3es11.3,a,3es11.3,a)') "three in a row: dv_x simultaneous ", dv(1, :), ", sequential ", &
         seq(1, :), " [m/s]"
      print '(a)', trim(what)
      call check(diff > 1.0e3_dp*tol, "simultaneous differs from sequential pairwise", failures)
   end subroutine three_in_a_row

   !> Two-sphere solution: dv_a = F n/M, dv_b = -F n/M, F = -c w/(1 + 2c/M).
   pure function pair_correction(va, vb, c, m, n) result(d)
      real(dp), intent(in) :: va(3), vb(3), c, m, n(3)
      real(dp) :: d(3, 2), f
      f = -c*dot_product(va - vb, n)/(1.0_dp + 2.0_dp*c/m)
      d(:, 1) = f*n/m
      d(:, 2) = -f*n/m
   end function pair_correction

   pure function gauss(a0, b0) result(x)
      real(dp), intent(in) :: a0(:, :), b0(:)
      real(dp) :: x(size(b0)), a(size(b0), size(b0)), b(size(b0)), f
      integer :: i, k, nn
      a = a0
      b = b0
      nn = size(b0)
      do k = 1, nn - 1
         do i = k + 1, nn
            f = a(i, k)/a(k, k)
            a(i, k:) = a(i, k:) - f*a(k, k:)
            b(i) = b(i) - f*b(k)
         end do
      end do
      do i = nn, 1, -1
         x(i) = (b(i) - dot_product(a(i, i + 1:), x(i + 1:)))/a(i, i)
      end do
   end function gauss

   !> lubrication_force is the coefficient times the normal approach rate; the floor and the
   !> threshold act on the coefficient; h_c = huge gives the seed's 1/gap.
   subroutine one_formula(failures)
      integer, intent(inout) :: failures
      real(dp) :: f(3), dx(3), h, h_c, seed
      h_c = 0.5_dp*R
      h = 0.1_dp*R
      dx = [2.0_dp*R + h, 0.0_dp, 0.0_dp]
      f = lubrication_force(R, R, eta, dx, [-U, 0.0_dp, 0.0_dp], 1.0e-3_dp*R, huge(1.0_dp))
      seed = -1.5_dp*pi*R**2*eta*(-U)/h
      call check(abs(f(1) - seed) <= 8.0_dp*eps*abs(seed) .and. all(f(2:3) == 0.0_dp), &
                 "h_c = huge: the seed's force", failures)
      call check(lubrication_coefficient(R, R, eta, 0.1_dp*h, h, h_c) == &
                 lubrication_coefficient(R, R, eta, h, h, h_c), "the floor holds the coefficient below gap_min", &
                 failures)
      call check(lubrication_coefficient(R, R, eta, h_c, 1.0e-3_dp*R, h_c) == 0.0_dp, "zero at h_c", failures)
      call check(lubrication_gap_floor(0.0_dp, h_c) == 1.0e-3_dp*h_c .and. lubrication_gap_floor(0.1_dp*R, h_c) == &
                 0.1_dp*R, "gap floor max(alpha, 1e-3 h_c)", failures)
   end subroutine one_formula

end program test_lubrication
