!> Random non-overlapping initial placement honouring the security zone alpha.
!>
!> 1. Orientations are drawn first, per particle: GIVEN (the axis as given; "aligned"
!>    is GIVEN with one axis for all), ISOTROPIC (uniform on the unit sphere, or the
!>    unit circle in 2-D) or PLANAR (uniform in the plane normal to the given axis;
!>    in 2-D the same as isotropic).
!> 2. Random sequential addition (RSA): particles are placed one by one (largest capsule
!>    first, so mixed families pack), each at uniform random positions until its capsule
!>    keeps a gap >= alpha to every placed particle and >= alpha/2 to walls, at most
!>    max_attempts tries. RSA jams (2-D disks at phi ~ 0.547, Feder 1980, J. Theor.
!>    Biol. 87:237; 3-D spheres ~ 0.38, Talbot et al. 2000, Colloids Surf. A 165:287)
!>    and slows down long before, so for dense targets:
!> 3. Relaxation (only if relax_sweeps > 0 and RSA did not place everybody): each
!>    particle RSA failed to place is put at its least-overlapping attempt, then Jacobi
!>    sweeps push every pair closer than alpha + margin apart along its contact normal
!>    (each by half the deficit; walls push the particle alone), translations only, so
!>    the drawn orientations are kept exactly. It stops when no gap is below alpha.
!>    This is an overlap-removal ("shake") step: the result is no longer a pure RSA
!>    ensemble, but it reaches fractions RSA cannot (e.g. the seed's 2-D disks at 50 %).
!>    The sweeps give up early when they stall: the total overlap O (sum over the pairs
!>    closer than alpha of the deficit) decays, when they succeed, roughly geometrically
!>    (halving every 20-700 sweeps in the tests); from the decay over the last
!>    STALL_WINDOW sweeps, the sweeps still needed to bring O down to alpha/100 are
!>    extrapolated, and when the total would exceed 4 relax_sweeps (or O did not
!>    decrease at all) the relaxation stops. A placement that succeeds is the same as
!>    without this test unless it would have crawled along such a plateau first.
!> If the target cannot be reached, stat = FOLD_INPUT_ERROR and the message gives the
!> fraction RSA reached. The stream is seeded (fold_random): same seed, same placement.
!> Progress: with the environment variable PYFOLD_PLACEMENT_PROGRESS set (non-empty),
!> lines `PLACEMENT rsa <particles tried> <n> <placed> <fraction placed> <target>` and
!> `PLACEMENT relax <sweep> <max sweeps> <pairs closer than alpha> <total overlap>`
!> go to stderr at most once a second (pyfold.scene.initial shows them).
module fold_placement
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_cell, only: cell_t, cell_min_image, cell_wrap, cell_volume, cell_from_fractional
   use fold_cell_list, only: cell_list_t, cell_list_setup, cell_list_insert, cell_list_build, cell_list_candidates
   use fold_particles, only: particle_set_t, particle_half_segment, particle_volume, FOLD_FIBRE, FOLD_SPHEROID
   use fold_segment, only: capsule_contact
   use fold_random, only: rng_t, rng_seed, rng_uniform
   use, intrinsic :: iso_fortran_env, only: error_unit
   implicit none
   private

   !> Orientation taken from the given axis
   integer(ip), parameter, public :: FOLD_ORIENT_GIVEN = 0
   !> Uniform on the unit sphere (3-D) or circle (2-D)
   integer(ip), parameter, public :: FOLD_ORIENT_ISOTROPIC = 1
   !> Uniform in the plane normal to the given axis (3-D); isotropic in 2-D
   integer(ip), parameter, public :: FOLD_ORIENT_PLANAR = 2

   public :: place_particles, random_orientation

   real(dp), parameter :: pi = acos(-1.0_dp)
   !> Sweeps over which the decay of the total overlap is measured (stall test)
   integer(ip), parameter, public :: STALL_WINDOW = 200

contains

   !> A random or given unit axis according to mode.
   subroutine random_orientation(rng, dim, mode, axis, p)
      type(rng_t), intent(inout) :: rng
      integer(ip), intent(in) :: dim, mode
      real(dp), intent(in) :: axis(:)
      real(dp), intent(out) :: p(:)
      real(dp) :: u1, u2, z, phi, e1(3), e2(3), a(3)

      if (mode == FOLD_ORIENT_GIVEN) then
         p = axis(1:dim)/norm2(axis(1:dim))
      else if (dim == 2 .or. mode == FOLD_ORIENT_ISOTROPIC) then
         call rng_uniform(rng, u1)
         call rng_uniform(rng, u2)
         phi = 2.0_dp*pi*u2
         if (dim == 2) then
            p = [cos(phi), sin(phi)]
         else
            z = 2.0_dp*u1 - 1.0_dp
            p = [sqrt(max(0.0_dp, 1.0_dp - z*z))*cos(phi), sqrt(max(0.0_dp, 1.0_dp - z*z))*sin(phi), z]
         end if
      else
         call rng_uniform(rng, u1)
         phi = 2.0_dp*pi*u1
         a = axis(1:3)/norm2(axis(1:3))
         ! orthonormal basis (e1, e2) of the plane normal to a
         if (abs(a(1)) < 0.9_dp) then
            e1 = [0.0_dp, -a(3), a(2)]
         else
            e1 = [a(3), 0.0_dp, -a(1)]
         end if
         e1 = e1/norm2(e1)
         e2 = [a(2)*e1(3) - a(3)*e1(2), a(3)*e1(1) - a(1)*e1(3), a(1)*e1(2) - a(2)*e1(1)]
         p = cos(phi)*e1 + sin(phi)*e2
      end if
   end subroutine random_orientation

   !> Place parts%n particles (shape, radius, length already set) in the cell:
   !> fills parts%x, parts%p (v, omega zeroed). See the module header.
   subroutine place_particles(cell, parts, alpha, seed, orient_mode, axis, max_attempts, relax_sweeps, &
                              n_rsa, sweeps_used, stat, errmsg)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      !> Security zone: minimum surface gap between particles (alpha/2 to walls) [m]
      real(dp), intent(in) :: alpha
      !> Seed of the random stream
      integer(i8), intent(in) :: seed
      !> Per-particle orientation mode (FOLD_ORIENT_*)
      integer(ip), intent(in) :: orient_mode(:)
      !> Per-particle axis (GIVEN) or plane normal (PLANAR), axis(dim, n) [-]
      real(dp), intent(in) :: axis(:, :)
      !> RSA attempts per particle (>= 1)
      integer(ip), intent(in) :: max_attempts
      !> Maximum relaxation sweeps (0: pure RSA, fail if RSA does not place all)
      integer(ip), intent(in) :: relax_sweeps
      !> Particles placed by RSA alone
      integer(ip), intent(out) :: n_rsa
      !> Relaxation sweeps used (0 if RSA sufficed)
      integer(ip), intent(out) :: sweeps_used
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      type(rng_t) :: rng
      type(cell_list_t) :: cl
      integer(ip) :: n, dim, k, m, a, nc, c
      integer(ip), allocatable :: order(:), cand(:)
      logical, allocatable :: placed(:)
      real(dp), allocatable :: hseg(:), vol(:), best_x(:, :)
      real(dp) :: rc, xtry(3), u, dmin, best, vdummy(3), phi_target, phi_rsa, vol_placed
      logical :: report, stalled
      integer(i8) :: clock_rate, clock_last
      integer :: env_len, env_stat
      character(len=8) :: env_buf

      dim = parts%dim
      n = parts%n
      n_rsa = 0
      sweeps_used = 0
      stat = FOLD_INPUT_ERROR
      errmsg = ""
      if (cell%dim /= dim) then
         write (errmsg, '(a,i0,a,i0)') "placement: cell dim ", cell%dim, " /= particle dim ", dim
         return
      end if
      if (.not. (alpha >= 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "placement: alpha must be >= 0, got ", alpha
         return
      end if
      if (max_attempts < 1 .or. relax_sweeps < 0) then
         write (errmsg, '(a,i0,a,i0)') "placement: need max_attempts >= 1 and relax_sweeps >= 0, got ", &
            max_attempts, ", ", relax_sweeps
         return
      end if
      if (size(orient_mode) /= n .or. size(axis, 1) /= dim .or. size(axis, 2) /= n) then
         errmsg = "placement: orient_mode must have shape (n,) and axis (dim, n)"
         return
      end if
      do k = 1, n
         if (.not. (parts%radius(k) > 0.0_dp) .or. parts%length(k) < 0.0_dp) then
            write (errmsg, '(a,i0,a)') "placement: particle ", k, " needs radius > 0 and length >= 0"
            return
         end if
         if (orient_mode(k) < FOLD_ORIENT_GIVEN .or. orient_mode(k) > FOLD_ORIENT_PLANAR) then
            write (errmsg, '(a,i0,a,i0,a)') "placement: particle ", k, " has orientation mode ", orient_mode(k), &
               " (allowed 0 given, 1 isotropic, 2 planar)"
            return
         end if
         if (orient_mode(k) /= FOLD_ORIENT_ISOTROPIC .and. .not. (norm2(axis(:, k)) > 0.0_dp)) then
            write (errmsg, '(a,i0,a)') "placement: particle ", k, " needs a non-zero axis for a given/planar orientation"
            return
         end if
      end do
      if (n == 0) then
         stat = FOLD_OK
         return
      end if

      call get_environment_variable("PYFOLD_PLACEMENT_PROGRESS", env_buf, env_len, env_stat)
      report = (env_stat == 0 .or. env_stat == -1) .and. env_len > 0
      call system_clock(clock_last, clock_rate)
      stalled = .false.
      allocate (hseg(n), vol(n), order(n), placed(n), cand(n), best_x(dim, n))
      hseg = particle_half_segment(parts%shape, parts%radius, parts%length)
      vol = particle_volume(dim, parts%shape, parts%radius, parts%length)
      phi_target = sum(vol)/cell_volume(cell)
      rc = 2.0_dp*maxval(hseg + parts%radius) + alpha
      rc = rc*(1.0_dp + 1.0e-9_dp)
      call cell_list_setup(cl, cell, rc, n, stat, errmsg)
      if (stat /= FOLD_OK) then
         errmsg = "placement: "//trim(errmsg)
         return
      end if
      stat = FOLD_INPUT_ERROR

      call rng_seed(rng, seed)
      do k = 1, n
         call random_orientation(rng, dim, orient_mode(k), axis(:, k), parts%p(:, k))
      end do
      parts%v = 0.0_dp
      parts%omega = 0.0_dp
      order = sort_by_extent(hseg + parts%radius)

      placed = .false.
      vol_placed = 0.0_dp
      do m = 1, n
         k = order(m)
         best = -huge(1.0_dp)
         do a = 1, max_attempts
            xtry = 0.0_dp
            do c = 1, dim
               call rng_uniform(rng, u)
               xtry(c) = u
            end do
            ! uniform in the primary cell (u L in the shear box, origin + B u on a deformed lattice)
            xtry(1:dim) = cell_from_fractional(cell, xtry(1:dim))
            parts%x(:, k) = xtry(1:dim)
            dmin = worst_clearance(k, best)
            if (dmin > best) then
               best = dmin
               best_x(:, k) = xtry(1:dim)
            end if
            if (dmin >= 0.0_dp) exit
         end do
         if (best >= 0.0_dp) then
            parts%x(:, k) = best_x(:, k)
            placed(k) = .true.
            n_rsa = n_rsa + 1
            vol_placed = vol_placed + vol(k)
            call cell_list_insert(cl, cell, k, parts%x(:, k))
         end if
         if (report) then
            if (due()) then
               write (error_unit, '(a,i0,1x,i0,1x,i0,1x,es13.6,1x,es13.6)') "PLACEMENT rsa ", m, n, n_rsa, &
                  vol_placed/cell_volume(cell), phi_target
               flush (error_unit)
            end if
         end if
      end do
      phi_rsa = sum(vol, mask=placed)/cell_volume(cell)
      if (n_rsa == n) then
         stat = FOLD_OK
         return
      end if

      if (relax_sweeps > 0) then
         do k = 1, n
            if (.not. placed(k)) parts%x(:, k) = best_x(:, k)
         end do
         call relax(sweeps_used)
         if (stat == FOLD_OK) return
      end if
      stat = FOLD_INPUT_ERROR
      if (stalled) then
         write (errmsg, '(a,a,a,a,a,i0,a,i0,a,i0,a,i0,a,i0,a)') "placement: could not reach volume fraction ", &
            fmt_fraction(phi_target), ": random sequential addition reached ", fmt_fraction(phi_rsa), " (", n_rsa, &
            " of ", n, " particles, ", max_attempts, " attempts each) and the relaxation stalled at sweep ", &
            sweeps_used, " (at the decay of the overlaps over the last ", STALL_WINDOW, &
            " sweeps it would not end within four times the allowed sweeps); lower the volume fraction or alpha"
      else
         write (errmsg, '(a,a,a,a,a,i0,a,i0,a,i0,a,i0,a)') "placement: could not reach volume fraction ", &
            fmt_fraction(phi_target), ": random sequential addition reached ", fmt_fraction(phi_rsa), " (", n_rsa, &
            " of ", n, " particles, ", max_attempts, " attempts each) and ", relax_sweeps, &
            " relaxation sweeps did not remove the overlaps; lower the volume fraction or alpha"
      end if

   contains

      !> True at most once a second (progress lines)
      logical function due()
         integer(i8) :: now
         call system_clock(now)
         due = real(now - clock_last, dp) >= real(clock_rate, dp)
         if (due) clock_last = now
      end function due

      !> min over placed neighbours and walls of (gap - required gap) for particle k at parts%x(:, k).
      !> Once it is negative and <= cutoff (the best clearance of the earlier attempts) the
      !> attempt can neither be accepted nor become the best, so the scan stops there: the
      !> value returned is then an upper bound, and the placement is the same as with a full scan.
      function worst_clearance(k, cutoff) result(dm)
         integer(ip), intent(in) :: k
         real(dp), intent(in) :: cutoff
         real(dp) :: dm, r(dim), dist, nrm(dim), s, t, ylo, yhi
         integer(ip) :: j
         dm = huge(1.0_dp)
         if (cell%walls) then
            ylo = parts%x(2, k) - hseg(k)*abs(parts%p(2, k)) - parts%radius(k)
            yhi = cell%lengths(2) - (parts%x(2, k) + hseg(k)*abs(parts%p(2, k))) - parts%radius(k)
            dm = min(ylo, yhi) - 0.5_dp*alpha
            if (dm < 0.0_dp .and. dm <= cutoff) return
         end if
         call cell_list_candidates(cl, cell, parts%x(:, k), cand, nc)
         do c = 1, nc
            j = cand(c)
            r = parts%x(:, k) - parts%x(:, j)
            call cell_min_image(cell, r)
            call capsule_contact(r, parts%p(:, k), hseg(k), parts%radius(k), parts%p(:, j), hseg(j), &
                                 parts%radius(j), dist, nrm, s, t)
            dm = min(dm, dist - alpha)
            if (dm < 0.0_dp .and. dm <= cutoff) return
         end do
      end function worst_clearance

      !> Jacobi overlap removal by translations (see the module header).
      subroutine relax(sweeps)
         integer(ip), intent(out) :: sweeps
         type(cell_list_t) :: cla
         real(dp), allocatable :: disp(:, :)
         real(dp) :: target, r(dim), dist, nrm(dim), s, t, deficit, y_lo, y_hi, tol, overlap, floor, rate
         real(dp) :: history(0:STALL_WINDOW)
         integer(ip) :: i, j, nbad, sw

         allocate (disp(dim, n))
         ! push a little beyond alpha so the iteration ends in finitely many sweeps
         target = alpha + max(0.05_dp*alpha, 1.0e-3_dp*minval(parts%radius))
         tol = 64.0_dp*epsilon(1.0_dp)*maxval(cell%lengths(1:dim))
         sweeps = 0
         floor = max(0.01_dp*alpha, 1.0e-6_dp*minval(parts%radius))
         do sw = 1, relax_sweeps + 1
            call cell_list_build(cla, cell, parts%x, rc, stat, errmsg)
            if (stat /= FOLD_OK) return
            disp = 0.0_dp
            nbad = 0
            overlap = 0.0_dp
            do i = 1, n
               if (cell%walls) then
                  y_lo = parts%x(2, i) - hseg(i)*abs(parts%p(2, i)) - parts%radius(i)
                  y_hi = cell%lengths(2) - (parts%x(2, i) + hseg(i)*abs(parts%p(2, i))) - parts%radius(i)
                  if (min(y_lo, y_hi) < 0.5_dp*alpha - tol) then
                     nbad = nbad + 1
                     overlap = overlap + (0.5_dp*alpha - min(y_lo, y_hi))
                  end if
                  if (y_lo < 0.5_dp*target) disp(2, i) = disp(2, i) + (0.5_dp*target - y_lo)
                  if (y_hi < 0.5_dp*target) disp(2, i) = disp(2, i) - (0.5_dp*target - y_hi)
               end if
               call cell_list_candidates(cla, cell, parts%x(:, i), cand, nc)
               do c = 1, nc
                  j = cand(c)
                  if (j <= i) cycle
                  r = parts%x(:, i) - parts%x(:, j)
                  call cell_min_image(cell, r)
                  call capsule_contact(r, parts%p(:, i), hseg(i), parts%radius(i), parts%p(:, j), hseg(j), &
                                       parts%radius(j), dist, nrm, s, t)
                  if (dist < alpha - tol) then
                     nbad = nbad + 1
                     overlap = overlap + (alpha - dist)
                  end if
                  if (dist < target) then
                     deficit = target - dist
                     disp(:, i) = disp(:, i) + 0.5_dp*deficit*nrm
                     disp(:, j) = disp(:, j) - 0.5_dp*deficit*nrm
                  end if
               end do
            end do
            if (nbad == 0) then
               stat = FOLD_OK
               return
            end if
            if (report) then
               if (due()) then
                  write (error_unit, '(a,i0,1x,i0,1x,i0,1x,es13.6)') "PLACEMENT relax ", sw - 1, relax_sweeps, &
                     nbad, overlap
                  flush (error_unit)
               end if
            end if
            ! stall test: history(mod(sw, W+1)) holds the overlap of sweep sw
            if (sw > STALL_WINDOW) then
               associate (before => history(mod(sw - STALL_WINDOW, STALL_WINDOW + 1)))
                  if (overlap >= before) then
                     stalled = .true.
                  else if (overlap > floor) then
                     rate = log(before/overlap)/real(STALL_WINDOW, dp)
                     stalled = real(sw, dp) + log(overlap/floor)/rate > 4.0_dp*real(relax_sweeps, dp)
                  end if
               end associate
               if (stalled) exit
            end if
            history(mod(sw, STALL_WINDOW + 1)) = overlap
            if (sw > relax_sweeps) exit
            sweeps = sw
            do i = 1, n
               parts%x(:, i) = parts%x(:, i) + disp(:, i)
               vdummy = 0.0_dp
               call cell_wrap(cell, parts%x(:, i), vdummy(1:dim))
            end do
         end do
         stat = FOLD_INPUT_ERROR
      end subroutine relax

   end subroutine place_particles

   !> A volume fraction as text, e.g. "0.4948".
   pure function fmt_fraction(phi) result(txt)
      real(dp), intent(in) :: phi
      character(len=:), allocatable :: txt
      character(len=32) :: buf
      write (buf, '(f12.4)') phi
      txt = trim(adjustl(buf))
   end function fmt_fraction

   !> Indices sorted by decreasing extent (stable: ties keep index order).
   function sort_by_extent(ext) result(order)
      real(dp), intent(in) :: ext(:)
      integer(ip) :: order(size(ext))
      integer :: i, j
      integer(ip) :: key
      order = [(int(i, ip), i=1, size(ext))]
      do i = 2, size(ext)
         key = order(i)
         j = i - 1
         do while (j >= 1)
            if (ext(order(j)) >= ext(key)) exit
            order(j + 1) = order(j)
            j = j - 1
         end do
         order(j + 1) = key
      end do
   end function sort_by_extent

end module fold_placement
