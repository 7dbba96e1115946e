!> Simulation cell: a periodic lattice that deforms with the mean flow, or Couette walls.
!>
!> Simple shear (G_xy the only non-zero entry, or G = 0): lattice basis a1 = (Lx,0,0),
!> a2 = (s,Ly,0), a3 = (0,0,Lz), s(t) = gamma_dot t Ly wrapped to [-Lx/2, Lx/2)
!> (Lees & Edwards 1972, J. Phys. C 5:1921; docs/physics.md#lees-edwards-skewed-lattice).
!> The image of a point x across the upper y-face sits at x + a2 and moves with the
!> extra velocity G.a2 = (gamma_dot Ly, 0, 0). This path is kept exactly as the original shear code.
!> Wall cell: no-slip walls at y = 0 and y = Ly moving at -U and +U (U = gamma_dot Ly/2),
!> periodic in x (and z); s = 0. Walls host simple shear only.
!>
!> Any other traceless G (planar or uniaxial elongation, a general gradient): the
!> lattice is carried by the mean flow, A(t) = exp(G t) A0 (columns = lattice vectors;
!> images of a point x are x + A(t) n, n integer, and move with the extra velocity
!> G A(t) n, so the whole periodic configuration is an affine image of itself). The
!> basis A(t) degenerates (long, nearly parallel vectors), so every time it is set the
!> basis is reduced to B = A U (U unimodular integer: the same lattice) by a
!> Minkowski-type reduction: pairwise size reduction b_i -= round(b_i.b_j/|b_j|^2) b_j
!> and, in 3-D, b_i -> b_i +- b_j +- b_k while a vector gets shorter; in 2-D this is
!> Lagrange-Gauss reduction and the result is Minkowski-reduced, in 3-D the loop stops
!> at a basis satisfying Minkowski's conditions with coefficients in {-1, 0, 1}
!> (Nguyen & Stehle 2009, ACM Trans. Algorithms 5:46, greedy reduction). The primary
!> cell is the parallelepiped origin + B [0,1)^dim centred on the cell centre c.
!> Its thickness along b_k is h_k = 1/|b*_k| (b*_k the dual vectors, rows of B^-1).
!> * Planar elongation G = diag(e, -e[, 0]) in a cell with Lx = Ly: Kraynik-Reinelt
!>   periodic boundary conditions (Kraynik & Reinelt 1992, Int. J. Multiphase Flow
!>   18:1045). The x-y lattice is a square of side Lx rotated by the magic angle
!>   theta = atan((sqrt(5) - 1)/2) (31.7 deg) from the stretching axis,
!>   a1 = Lx (cos theta, -sin theta), a2 = Lx (sin theta, cos theta); then
!>   A0^-1 diag(lambda, 1/lambda) A0 = [[2,1],[1,1]] with lambda = (3 + sqrt 5)/2, so
!>   after the Hencky strain e t = ln lambda = 0.9624 the lattice is the initial one
!>   again (another basis of it). The lattice is therefore computed from
!>   t mod (ln lambda/|e|): runs can last indefinitely and the cell is a pure function
!>   of t (restarts are reproducible). The primary cell at t = 0 is that rotated
!>   square centred on c (not the box [0,Lx) x [0,Ly)).
!> * Other flows (uniaxial elongation, a general gradient, planar elongation with
!>   Lx /= Ly): A0 = diag(lengths), no reproducible remap exists; the reduced cell
!>   thins and a run may go on only while every h_k exceeds twice the contact range
!>   (cell_admissible_time gives the last admissible step; fold_cell_list refuses a
!>   thinner cell, which stops a run that gets there cleanly).
!>
!> Frame rule (the single source of truth for the mean flow): the imposed mean
!> velocity is
!>     u_mean(x) = G . (x - c),   c = lengths/2 (cell centre),
!> so the centre is at rest and the walls move at -/+U. Positions may be kept wrapped
!> (then cell_wrap applies the velocity jump -G.(B n) when a particle is moved by the
!> lattice vector -B n) or unwrapped: u_mean is affine, so both give the same velocities
!> up to the image shift that cell_wrap adds, and every distance goes through
!> cell_min_image.
module fold_cell
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_mat3, only: adjugate3
   use fold_check, only: check_dim
   use fold_matrix_exp, only: expm3
   implicit none
   private

   !> Simple shear G_xy (or no flow): Lees-Edwards offset, the original code path
   integer(ip), parameter, public :: FOLD_FLOW_SHEAR = 0
   !> Planar elongation with Kraynik-Reinelt remapping (indefinite runs)
   integer(ip), parameter, public :: FOLD_FLOW_PLANAR_KR = 1
   !> Any other traceless gradient: deforming lattice, time-limited
   integer(ip), parameter, public :: FOLD_FLOW_GENERAL = 2

   !> The simulation cell.
   type, public :: cell_t
      !> Spatial dimension (2 or 3)
      integer(ip) :: dim = 3
      !> Edge lengths Lx, Ly, Lz (Lz unused in 2-D) [m]
      real(dp) :: lengths(3) = 1.0_dp
      !> True: no-slip walls at y = 0, Ly (moving at -/+U); false: fully periodic
      logical :: walls = .false.
      !> Lees-Edwards offset s of the lattice vector a2 = (s, Ly, 0), in [-Lx/2, Lx/2) [m]
      real(dp) :: shear_offset = 0.0_dp
      !> Imposed velocity gradient G_ij = du_i/dx_j [1/s]
      real(dp) :: G(3, 3) = 0.0_dp
      !> FOLD_FLOW_SHEAR / FOLD_FLOW_PLANAR_KR / FOLD_FLOW_GENERAL (set by cell_init)
      integer(ip) :: flow = FOLD_FLOW_SHEAR
      !> Time the lattice is set for [s]
      real(dp) :: time = 0.0_dp
      !> Lattice at t = 0, A0 (columns; deforming flows) [m]
      real(dp) :: lattice0(3, 3) = 0.0_dp
      !> Reduced basis B(t) of the current lattice (columns; deforming flows) [m]
      real(dp) :: basis(3, 3) = 0.0_dp
      !> B^-1: row k is the dual vector b*_k [1/m]
      real(dp) :: dual(3, 3) = 0.0_dp
      !> Corner of the primary cell origin + B [0,1)^dim, centred on lengths/2 [m]
      real(dp) :: origin(3) = 0.0_dp
      !> Thickness h_k = 1/|b*_k| of the primary cell along each reduced vector [m]
      real(dp) :: thickness(3) = 1.0_dp
      !> Kraynik-Reinelt time period ln((3 + sqrt 5)/2)/|e| (0 otherwise) [s]
      real(dp) :: period = 0.0_dp
   end type cell_t

   public :: cell_init, cell_set_time, cell_advance, cell_min_image, cell_wrap
   public :: cell_shear_rate, cell_wall_speed, cell_mean_velocity, cell_volume
   public :: cell_deforming, cell_min_thickness, cell_from_fractional, cell_admissible_time, cell_lattice
   public :: reduce_basis

   !> Kraynik-Reinelt: eigenvalue of [[2,1],[1,1]], tan of the magic angle
   real(dp), parameter :: KR_LAMBDA = (3.0_dp + sqrt(5.0_dp))/2.0_dp
   real(dp), parameter :: KR_TAN = (sqrt(5.0_dp) - 1.0_dp)/2.0_dp

contains

   !> Build a cell; checks lengths > 0, a finite traceless G (simple shear only with
   !> walls) and picks the lattice of the flow (module header).
   subroutine cell_init(cell, dim, lengths, walls, G, stat, errmsg)
      type(cell_t), intent(out) :: cell
      !> Spatial dimension (2 or 3)
      integer(ip), intent(in) :: dim
      !> Edge lengths (Lx, Ly, Lz); Lz ignored in 2-D [m]
      real(dp), intent(in) :: lengths(3)
      !> No-slip walls at y = 0, Ly
      logical, intent(in) :: walls
      !> Velocity gradient G_ij = du_i/dx_j [1/s]
      real(dp), intent(in) :: G(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      real(dp) :: other(3, 3), trace, cs, sn
      integer :: k

      call check_dim(dim, "cell_init", stat, errmsg)
      if (stat /= FOLD_OK) return
      stat = FOLD_INPUT_ERROR
      if (.not. all(lengths(1:dim) > 0.0_dp) .or. .not. all(lengths(1:dim) < huge(1.0_dp))) then
         write (errmsg, '(a,3es11.3)') "cell_init: cell_lengths must be finite and > 0, got ", lengths(1:dim)
         return
      end if
      if (.not. all(abs(G) < huge(1.0_dp))) then
         errmsg = "cell_init: velocity_gradient must be finite"
         return
      end if
      trace = G(1, 1) + G(2, 2)
      if (dim == 3) trace = trace + G(3, 3)
      if (abs(trace) > 1.0e-12_dp*max(1.0_dp, maxval(abs(G)))) then
         write (errmsg, '(a,es11.3,a)') "cell_init: velocity_gradient must be traceless (incompressible flow; "// &
            "the lattice keeps its volume), trace = ", trace, " (allowed |trace| <= 1e-12 max|G_ij|)"
         return
      end if
      if (dim == 2 .and. (any(G(3, :) /= 0.0_dp) .or. any(G(:, 3) /= 0.0_dp))) then
         errmsg = "cell_init: a 2-D cell needs a velocity_gradient with zero third row and column"
         return
      end if
      other = G
      other(1, 2) = 0.0_dp
      if (walls .and. any(other /= 0.0_dp)) then
         errmsg = "cell_init: walls (Couette cell) host simple shear only: velocity_gradient must have "// &
                  "G[0,1] = du_x/dy as its only non-zero entry"
         return
      end if
      cell%dim = dim
      cell%lengths = 1.0_dp
      cell%lengths(1:dim) = lengths(1:dim)
      cell%walls = walls
      cell%G = G
      cell%shear_offset = 0.0_dp
      cell%time = 0.0_dp
      cell%flow = FOLD_FLOW_SHEAR
      if (any(other /= 0.0_dp)) then
         cell%flow = FOLD_FLOW_GENERAL
         cell%lattice0 = 0.0_dp
         do k = 1, 3
            cell%lattice0(k, k) = cell%lengths(k)
         end do
         other = G
         other(1, 1) = 0.0_dp
         other(2, 2) = 0.0_dp
         if (G(1, 1) /= 0.0_dp .and. G(2, 2) == -G(1, 1) .and. all(other == 0.0_dp) .and. &
             abs(lengths(1) - lengths(2)) <= 1.0e-12_dp*lengths(1)) then
            cell%flow = FOLD_FLOW_PLANAR_KR
            cs = 1.0_dp/sqrt(1.0_dp + KR_TAN**2)
            sn = KR_TAN*cs
            cell%lattice0(1:2, 1) = lengths(1)*[cs, -sn]
            cell%lattice0(1:2, 2) = lengths(1)*[sn, cs]
            cell%period = log(KR_LAMBDA)/abs(G(1, 1))
         end if
         call cell_set_time(cell, 0.0_dp)
      end if
      stat = FOLD_OK
   end subroutine cell_init

   !> Shear rate gamma_dot = G(1,2) [1/s].
   pure function cell_shear_rate(cell) result(gd)
      type(cell_t), intent(in) :: cell
      real(dp) :: gd
      gd = cell%G(1, 2)
   end function cell_shear_rate

   !> Wall speed U = gamma_dot Ly / 2: the walls move at -U (y = 0) and +U (y = Ly) [m/s].
   pure function cell_wall_speed(cell) result(u)
      type(cell_t), intent(in) :: cell
      real(dp) :: u
      u = 0.5_dp*cell%G(1, 2)*cell%lengths(2)
   end function cell_wall_speed

   !> Volume (3-D) or area (2-D) of the cell [m^dim].
   pure function cell_volume(cell) result(vol)
      type(cell_t), intent(in) :: cell
      real(dp) :: vol
      vol = product(cell%lengths(1:cell%dim))
   end function cell_volume

   !> Wrap an offset into [-Lx/2, Lx/2).
   pure function wrap_offset(s, lx) result(w)
      real(dp), intent(in) :: s, lx
      real(dp) :: w
      w = modulo(s + 0.5_dp*lx, lx) - 0.5_dp*lx
   end function wrap_offset

   !> Set the lattice for time t. Shear: the Lees-Edwards offset s = gamma_dot t Ly
   !> wrapped (0 with walls). Deforming flows: A(t) = exp(G t') A0 reduced, t' = t
   !> (general) or t mod the Kraynik-Reinelt period (planar elongation).
   pure subroutine cell_set_time(cell, t)
      type(cell_t), intent(inout) :: cell
      !> Time since the lattice was A0 [s]
      real(dp), intent(in) :: t
      real(dp) :: tl, a(3, 3)
      cell%time = t
      if (cell%flow == FOLD_FLOW_SHEAR) then
         if (cell%walls) then
            cell%shear_offset = 0.0_dp
         else
            cell%shear_offset = wrap_offset(cell%G(1, 2)*t*cell%lengths(2), cell%lengths(1))
         end if
         return
      end if
      tl = t
      if (cell%flow == FOLD_FLOW_PLANAR_KR) tl = t - cell%period*floor(t/cell%period)
      a = matmul(expm3(tl*cell%G), cell%lattice0)
      call reduce_basis(cell%dim, a)
      call set_basis(cell, a)
   end subroutine cell_set_time

   !> Advance the lattice by dt (shear: s += gamma_dot Ly dt, wrapped).
   pure subroutine cell_advance(cell, dt)
      type(cell_t), intent(inout) :: cell
      !> Time increment [s]
      real(dp), intent(in) :: dt
      if (cell%flow /= FOLD_FLOW_SHEAR) then
         call cell_set_time(cell, cell%time + dt)
         return
      end if
      cell%time = cell%time + dt
      if (.not. cell%walls) then
         cell%shear_offset = wrap_offset(cell%shear_offset + cell%G(1, 2)*dt*cell%lengths(2), cell%lengths(1))
      end if
   end subroutine cell_advance

   !> True when the lattice deforms with the flow (not the Lees-Edwards shear path).
   pure logical function cell_deforming(cell)
      type(cell_t), intent(in) :: cell
      cell_deforming = cell%flow /= FOLD_FLOW_SHEAR
   end function cell_deforming

   !> Current lattice vectors (columns; 2-D: third column e_z): the reduced basis of a
   !> deforming cell, (Lx,0,0), (s,Ly,0), (0,0,Lz) in shear [m].
   pure function cell_lattice(cell) result(b)
      type(cell_t), intent(in) :: cell
      real(dp) :: b(3, 3)
      integer :: k
      if (cell%flow /= FOLD_FLOW_SHEAR) then
         b = cell%basis
         return
      end if
      b = 0.0_dp
      do k = 1, 3
         b(k, k) = cell%lengths(k)
      end do
      b(1, 2) = cell%shear_offset
   end function cell_lattice

   !> Smallest thickness of the primary cell between opposite periodic faces (the
   !> largest interaction range r with a unique image within r is half of it) [m].
   pure function cell_min_thickness(cell) result(h)
      type(cell_t), intent(in) :: cell
      real(dp) :: h
      real(dp) :: ly
      if (cell%flow /= FOLD_FLOW_SHEAR) then
         h = minval(cell%thickness(1:cell%dim))
         return
      end if
      ! skewed shear lattice: the x-faces are Lx Ly / sqrt(Ly^2 + s^2) apart, but the
      ! shear path searches x images directly, so the edges themselves bound the range
      h = cell%lengths(1)
      if (cell%dim == 3) h = min(h, cell%lengths(3))
      if (.not. cell%walls) then
         ly = cell%lengths(2)
         h = min(h, ly)
      end if
   end function cell_min_thickness

   !> Position of fractional coordinates u in [0,1)^dim of the primary cell: u*L in
   !> the shear/wall cell (the box [0,L) tiles the skewed lattice), origin + B u
   !> otherwise (uniform u gives a uniform point of the periodic cell) [m].
   pure function cell_from_fractional(cell, u) result(x)
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: u(:)
      real(dp) :: x(size(u))
      integer :: d
      d = size(u)
      if (cell%flow == FOLD_FLOW_SHEAR) then
         x = u*cell%lengths(1:d)
      else
         x = cell%origin(1:d) + matmul(cell%basis(1:d, 1:d), u)
      end if
   end function cell_from_fractional

   !> Largest time t_ok = k dt <= t_end (k integer) such that the cell at every step time
   !> j dt (j <= k) is thicker than 2 rc, so a contact search of range rc has a unique
   !> minimum image; t_end itself for the shear and Kraynik-Reinelt cells (if thick
   !> enough at t = 0), -1 when even t = 0 fails. `cell` is the cell at t = 0.
   pure function cell_admissible_time(cell, rc, dt, t_end) result(t_ok)
      type(cell_t), intent(in) :: cell
      !> Interaction range [m]
      real(dp), intent(in) :: rc
      !> Time step (> 0) [s]
      real(dp), intent(in) :: dt
      !> Requested end time [s]
      real(dp), intent(in) :: t_end
      real(dp) :: t_ok
      type(cell_t) :: c
      integer(kind=8) :: k, nsteps
      c = cell
      t_ok = -1.0_dp
      call cell_set_time(c, 0.0_dp)
      if (.not. (cell_min_thickness(c) > 2.0_dp*rc)) return
      if (cell%flow /= FOLD_FLOW_GENERAL) then
         if (cell%flow == FOLD_FLOW_SHEAR) then
            t_ok = t_end
            return
         end if
         ! Kraynik-Reinelt: the lattice repeats, one period decides
         nsteps = min(int(t_end/dt + 0.5_dp, kind=8), int(cell%period/dt, kind=8) + 2)
      else
         nsteps = int(t_end/dt + 0.5_dp, kind=8)
      end if
      do k = 1, nsteps
         call cell_set_time(c, real(k, dp)*dt)
         if (.not. (cell_min_thickness(c) > 2.0_dp*rc)) then
            t_ok = real(k - 1, dp)*dt
            return
         end if
      end do
      t_ok = t_end
   end function cell_admissible_time

   !> Store a reduced basis with its dual vectors, thicknesses and primary-cell origin.
   pure subroutine set_basis(cell, a)
      type(cell_t), intent(inout) :: cell
      real(dp), intent(in) :: a(3, 3)
      integer :: d, k
      d = cell%dim
      cell%basis = 0.0_dp
      cell%basis(1:d, 1:d) = a(1:d, 1:d)
      if (d == 2) cell%basis(3, 3) = 1.0_dp
      cell%dual = inverse3(cell%basis)
      cell%thickness = 1.0_dp
      do k = 1, d
         cell%thickness(k) = 1.0_dp/norm2(cell%dual(k, 1:d))
      end do
      cell%origin = 0.0_dp
      cell%origin(1:d) = 0.5_dp*cell%lengths(1:d) - 0.5_dp*sum(cell%basis(1:d, 1:d), dim=2)
   end subroutine set_basis

   !> Inverse of a non-singular 3x3 matrix (adjugate / determinant).
   pure function inverse3(a) result(b)
      real(dp), intent(in) :: a(3, 3)
      real(dp) :: b(3, 3), det
      b = adjugate3(a)
      det = a(1, 1)*b(1, 1) + a(1, 2)*b(2, 1) + a(1, 3)*b(3, 1)
      b = b/det
   end function inverse3

   !> Minkowski-type reduction of the lattice basis a(:, 1:d) in place (module header):
   !> size-reduce every pair, and in 3-D try b_i +- b_j +- b_k, while some vector gets
   !> strictly shorter (by more than a relative 1e-12, so the loop terminates), then
   !> order by length and make the basis right-handed. Deterministic.
   pure subroutine reduce_basis(d, a)
      integer(ip), intent(in) :: d
      real(dp), intent(inout) :: a(3, 3)
      real(dp), parameter :: shrink = 1.0_dp - 1.0e-12_dp
      real(dp) :: trial(3), tmp(3), m, l2(3)
      integer :: it, i, j, k, sj, sk
      logical :: changed

      do it = 1, 10000
         changed = .false.
         do i = 1, d
            do j = 1, d
               if (i == j) cycle
               m = anint(dot_product(a(1:d, i), a(1:d, j))/dot_product(a(1:d, j), a(1:d, j)))
               if (m == 0.0_dp) cycle
               trial(1:d) = a(1:d, i) - m*a(1:d, j)
               if (dot_product(trial(1:d), trial(1:d)) < shrink*dot_product(a(1:d, i), a(1:d, i))) then
                  a(1:d, i) = trial(1:d)
                  changed = .true.
               end if
            end do
         end do
         if (d == 3) then
            do i = 1, 3
               j = modulo(i, 3) + 1
               k = modulo(i + 1, 3) + 1
               do sj = -1, 1, 2
                  do sk = -1, 1, 2
                     trial = a(:, i) + sj*a(:, j) + sk*a(:, k)
                     if (dot_product(trial, trial) < shrink*dot_product(a(:, i), a(:, i))) then
                        a(:, i) = trial
                        changed = .true.
                     end if
                  end do
               end do
            end do
         end if
         if (.not. changed) exit
      end do
      ! shortest first (insertion sort, stable)
      do i = 1, d
         l2(i) = dot_product(a(1:d, i), a(1:d, i))
      end do
      do i = 2, d
         j = i
         do while (j > 1)
            if (l2(j - 1) <= l2(j)) exit
            tmp = a(:, j); a(:, j) = a(:, j - 1); a(:, j - 1) = tmp
            m = l2(j); l2(j) = l2(j - 1); l2(j - 1) = m
            j = j - 1
         end do
      end do
      if (d == 2) then
         if (a(1, 1)*a(2, 2) - a(1, 2)*a(2, 1) < 0.0_dp) a(1:2, 2) = -a(1:2, 2)
      else
         if (dot_product(a(:, 3), [a(2, 1)*a(3, 2) - a(3, 1)*a(2, 2), a(3, 1)*a(1, 2) - a(1, 1)*a(3, 2), &
                                   a(1, 1)*a(2, 2) - a(2, 1)*a(1, 2)]) < 0.0_dp) a(:, 3) = -a(:, 3)
      end if
   end subroutine reduce_basis

   !> Replace a displacement dx = x_i - x_j by its shortest periodic image.
   !> Shear: the image rows n_y = round(dy/Ly) - 1 .. +1 are all tried, so the result
   !> is the true minimum image on the skewed lattice even for |s| = Lx/2.
   !> Deforming lattice: f = B^-1 dx rounded to the nearest integers gives r0 = B (f -
   !> round f); if |r0| < h_min/2 it is the unique minimum (any other image is at least
   !> h_min - |r0| away). Otherwise every image r = r0 - B n with |r| <= |r0| has
   !> |f_k - n_k| = |b*_k . r| <= |r0|/h_k, so the integer box
   !> n_k in [f_k - |r0|/h_k, f_k + |r0|/h_k] is searched exhaustively: exact for any
   !> lattice, cheap for a reduced one (|r0|/h_k ~ 1).
   pure subroutine cell_min_image(cell, dx)
      type(cell_t), intent(in) :: cell
      !> Displacement, replaced in place by its minimum image [m]
      real(dp), intent(inout) :: dx(:)
      real(dp) :: lx, ly, best(3), trial(3), d2, d2best
      integer :: ny0, ny

      if (cell%flow /= FOLD_FLOW_SHEAR) then
         call min_image_lattice(cell, dx)
         return
      end if
      lx = cell%lengths(1)
      ly = cell%lengths(2)
      if (cell%dim == 3) dx(3) = dx(3) - cell%lengths(3)*nearest_whole(dx(3)/cell%lengths(3))
      if (cell%walls) then
         dx(1) = dx(1) - lx*nearest_whole(dx(1)/lx)
         return
      end if
      ny0 = int(nearest_whole(dx(2)/ly))
      d2best = huge(1.0_dp)
      best = 0.0_dp
      do ny = ny0 - 1, ny0 + 1
         trial = 0.0_dp
         trial(1) = dx(1) - ny*cell%shear_offset
         trial(2) = dx(2) - ny*ly
         trial(1) = trial(1) - lx*nearest_whole(trial(1)/lx)
         d2 = trial(1)**2 + trial(2)**2
         ! strict < keeps the central row on exact ties: the result is deterministic
         if (d2 < d2best .or. ny == ny0 .and. d2 <= d2best) then
            d2best = d2
            best = trial
         end if
      end do
      dx(1:2) = best(1:2)
   end subroutine cell_min_image

   !> anint(x) (nearest whole number, halves away from zero, signed zero kept),
   !> bit-identical, without the libm round() call that anint compiles to: the
   !> minimum image runs for every candidate pair of a contact search. Truncation by
   !> an integer conversion is exact for |x| < 2^52, x - trunc(x) is then exact too;
   !> larger |x| are already whole (and NaN / Inf pass through unchanged).
   elemental function nearest_whole(x) result(y)
      real(dp), intent(in) :: x
      real(dp) :: y
      real(dp), parameter :: whole_above = 2.0_dp**52
      if (.not. (abs(x) < whole_above)) then
         y = x
         return
      end if
      y = real(int(x, i8), dp)
      if (abs(x - y) >= 0.5_dp) y = y + sign(1.0_dp, x)
      y = sign(y, x)
   end function nearest_whole

   !> Minimum image on the reduced deforming lattice (see cell_min_image).
   pure subroutine min_image_lattice(cell, dx)
      type(cell_t), intent(in) :: cell
      real(dp), intent(inout) :: dx(:)
      real(dp) :: f(3), r0(3), trial(3), best(3), d2, d2best, rho(3), hmin
      integer :: d, lo(3), hi(3), n1, n2, n3

      d = cell%dim
      f = 0.0_dp
      f(1:d) = matmul(cell%dual(1:d, 1:d), dx(1:d))
      f(1:d) = f(1:d) - nearest_whole(f(1:d))
      r0 = 0.0_dp
      r0(1:d) = matmul(cell%basis(1:d, 1:d), f(1:d))
      d2best = dot_product(r0, r0)
      hmin = minval(cell%thickness(1:d))
      if (d2best < 0.25_dp*hmin*hmin) then
         dx(1:d) = r0(1:d)
         return
      end if
      rho = 0.0_dp
      rho(1:d) = sqrt(d2best)/cell%thickness(1:d)*(1.0_dp + 1.0e-12_dp)
      lo = 0
      hi = 0
      lo(1:d) = ceiling(f(1:d) - rho(1:d))
      hi(1:d) = floor(f(1:d) + rho(1:d))
      best = r0
      do n3 = lo(3), hi(3)
         do n2 = lo(2), hi(2)
            do n1 = lo(1), hi(1)
               if (n1 == 0 .and. n2 == 0 .and. n3 == 0) cycle
               trial = r0 - (n1*cell%basis(:, 1) + n2*cell%basis(:, 2) + n3*cell%basis(:, 3))
               if (d == 2) trial(3) = 0.0_dp
               d2 = dot_product(trial, trial)
               ! strict <: ties keep the earlier candidate (r0 first), deterministic
               if (d2 < d2best) then
                  d2best = d2
                  best = trial
               end if
            end do
         end do
      end do
      dx(1:d) = best(1:d)
   end subroutine min_image_lattice

   !> Wrap a position into the primary cell. Shear: crossing a sheared y-face (n_y
   !> lattice rows) shifts x by -n_y a2 and the velocity by -n_y G.a2 = -n_y gamma_dot
   !> Ly e_x (Lees-Edwards velocity jump); with walls, y is left unchanged. Deforming
   !> lattice: n = floor(B^-1 (x - origin)), x -= B n, v -= G B n.
   pure subroutine cell_wrap(cell, x, v)
      type(cell_t), intent(in) :: cell
      !> Position, wrapped in place [m]
      real(dp), intent(inout) :: x(:)
      !> Velocity, jumped in place when a sheared face is crossed [m/s]
      real(dp), intent(inout) :: v(:)
      real(dp) :: ny, f(3), shift(3)
      integer :: d

      if (cell%flow /= FOLD_FLOW_SHEAR) then
         d = cell%dim
         f = 0.0_dp
         f(1:d) = floor(matmul(cell%dual(1:d, 1:d), x(1:d) - cell%origin(1:d)))
         if (any(f(1:d) /= 0.0_dp)) then
            shift = 0.0_dp
            shift(1:d) = matmul(cell%basis(1:d, 1:d), f(1:d))
            x(1:d) = x(1:d) - shift(1:d)
            v(1:d) = v(1:d) - matmul(cell%G(1:d, 1:d), shift(1:d))
         end if
         return
      end if
      if (.not. cell%walls) then
         ny = floor(x(2)/cell%lengths(2))
         if (ny /= 0.0_dp) then
            x(1) = x(1) - ny*cell%shear_offset
            x(2) = x(2) - ny*cell%lengths(2)
            v(1) = v(1) - ny*cell%G(1, 2)*cell%lengths(2)
            ! round-off can leave y == Ly after the subtraction
            if (x(2) >= cell%lengths(2)) x(2) = 0.0_dp
         end if
      end if
      x(1) = modulo(x(1), cell%lengths(1))
      if (x(1) >= cell%lengths(1)) x(1) = 0.0_dp
      if (cell%dim == 3) then
         x(3) = modulo(x(3), cell%lengths(3))
         if (x(3) >= cell%lengths(3)) x(3) = 0.0_dp
      end if
   end subroutine cell_wrap

   !> Imposed mean velocity u = G.(x - c), c the cell centre (see module header) [m/s].
   pure function cell_mean_velocity(cell, x) result(u)
      type(cell_t), intent(in) :: cell
      !> Position (dim) [m]
      real(dp), intent(in) :: x(:)
      real(dp) :: u(size(x))
      integer :: i
      do i = 1, size(x)
         u(i) = dot_product(cell%G(i, 1:size(x)), x - 0.5_dp*cell%lengths(1:size(x)))
      end do
   end function cell_mean_velocity

end module fold_cell
