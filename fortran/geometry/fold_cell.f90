!> Simulation cell: periodic with a Lees-Edwards skewed lattice, or Couette walls.
!>
!> Periodic cell (physics.md section 3): lattice basis a1 = (Lx,0,0), a2 = (s,Ly,0),
!> a3 = (0,0,Lz), s(t) = gamma_dot t Ly wrapped to [-Lx/2, Lx/2) (Lees & Edwards 1972,
!> J. Phys. C 5:1921). The image of a point x across the upper y-face sits at x + a2
!> and moves with the extra velocity G.a2 = (gamma_dot Ly, 0, 0).
!> Wall cell: no-slip walls at y = 0 and y = Ly moving at -U and +U (U = gamma_dot Ly/2),
!> periodic in x (and z); s = 0.
!>
!> Frame rule (the single source of truth for the mean flow): the primary cell is
!> [0,Lx) x [0,Ly) x [0,Lz) and the imposed mean velocity is
!>     u_mean(x) = G . (x - c),   c = lengths/2 (cell centre),
!> so the centre is at rest and the walls move at -/+U. Positions may be kept wrapped
!> (then cell_wrap applies the velocity jump when a particle crosses a sheared face)
!> or unwrapped: u_mean is affine, so both give the same velocities up to the image
!> shift G.a that cell_wrap adds, and every distance goes through cell_min_image.
!> Only simple shear u = gamma_dot (y - Ly/2) e_x is compatible with a periodic
!> (or wall) cell that does not deform, so cell_init rejects any other G.
module fold_cell
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   implicit none
   private

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
   end type cell_t

   public :: cell_init, cell_set_time, cell_advance, cell_min_image, cell_wrap
   public :: cell_shear_rate, cell_wall_speed, cell_mean_velocity, cell_volume

contains

   !> Build a cell; checks lengths > 0 and that G is a simple shear G(1,2) (or zero).
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

      real(dp) :: other(3, 3)

      stat = FOLD_INPUT_ERROR
      errmsg = ""
      if (dim /= 2 .and. dim /= 3) then
         write (errmsg, '(a,i0)') "cell_init: dim must be 2 or 3, got ", dim
         return
      end if
      if (.not. all(lengths(1:dim) > 0.0_dp) .or. .not. all(lengths(1:dim) < huge(1.0_dp))) then
         write (errmsg, '(a,3es11.3)') "cell_init: cell_lengths must be finite and > 0, got ", lengths(1:dim)
         return
      end if
      if (.not. all(abs(G) < huge(1.0_dp))) then
         errmsg = "cell_init: velocity_gradient must be finite"
         return
      end if
      other = G
      other(1, 2) = 0.0_dp
      if (any(other /= 0.0_dp)) then
         errmsg = "cell_init: velocity_gradient must be a simple shear (only G[0,1] = du_x/dy may be non-zero): "// &
                  "a periodic or wall cell that does not deform cannot host another mean flow"
         return
      end if
      cell%dim = dim
      cell%lengths = 1.0_dp
      cell%lengths(1:dim) = lengths(1:dim)
      cell%walls = walls
      cell%G = G
      cell%shear_offset = 0.0_dp
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

   !> Set the Lees-Edwards offset for time t: s = gamma_dot t Ly wrapped (0 with walls).
   pure subroutine cell_set_time(cell, t)
      type(cell_t), intent(inout) :: cell
      !> Time since the lattice was orthogonal [s]
      real(dp), intent(in) :: t
      if (cell%walls) then
         cell%shear_offset = 0.0_dp
      else
         cell%shear_offset = wrap_offset(cell%G(1, 2)*t*cell%lengths(2), cell%lengths(1))
      end if
   end subroutine cell_set_time

   !> Advance the Lees-Edwards offset by dt (s += gamma_dot Ly dt, wrapped).
   pure subroutine cell_advance(cell, dt)
      type(cell_t), intent(inout) :: cell
      !> Time increment [s]
      real(dp), intent(in) :: dt
      if (.not. cell%walls) then
         cell%shear_offset = wrap_offset(cell%shear_offset + cell%G(1, 2)*dt*cell%lengths(2), cell%lengths(1))
      end if
   end subroutine cell_advance

   !> Replace a displacement dx = x_i - x_j by its shortest periodic (sheared) image.
   !> The image rows n_y = round(dy/Ly) - 1 .. +1 are all tried, so the result is the
   !> true minimum image on the skewed lattice even for |s| = Lx/2.
   pure subroutine cell_min_image(cell, dx)
      type(cell_t), intent(in) :: cell
      !> Displacement, replaced in place by its minimum image [m]
      real(dp), intent(inout) :: dx(:)
      real(dp) :: lx, ly, best(3), trial(3), d2, d2best
      integer :: ny0, ny

      lx = cell%lengths(1)
      ly = cell%lengths(2)
      if (cell%dim == 3) dx(3) = dx(3) - cell%lengths(3)*anint(dx(3)/cell%lengths(3))
      if (cell%walls) then
         dx(1) = dx(1) - lx*anint(dx(1)/lx)
         return
      end if
      ny0 = nint(dx(2)/ly)
      d2best = huge(1.0_dp)
      best = 0.0_dp
      do ny = ny0 - 1, ny0 + 1
         trial = 0.0_dp
         trial(1) = dx(1) - ny*cell%shear_offset
         trial(2) = dx(2) - ny*ly
         trial(1) = trial(1) - lx*anint(trial(1)/lx)
         d2 = trial(1)**2 + trial(2)**2
         ! strict < keeps the central row on exact ties: the result is deterministic
         if (d2 < d2best .or. ny == ny0 .and. d2 <= d2best) then
            d2best = d2
            best = trial
         end if
      end do
      dx(1:2) = best(1:2)
   end subroutine cell_min_image

   !> Wrap a position into the primary cell; crossing a sheared y-face (n_y lattice
   !> rows) shifts x by -n_y a2 and the velocity by -n_y G.a2 = -n_y gamma_dot Ly e_x
   !> (Lees-Edwards velocity jump). With walls, y is left unchanged.
   pure subroutine cell_wrap(cell, x, v)
      type(cell_t), intent(in) :: cell
      !> Position, wrapped in place [m]
      real(dp), intent(inout) :: x(:)
      !> Velocity, jumped in place when a sheared face is crossed [m/s]
      real(dp), intent(inout) :: v(:)
      real(dp) :: ny

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
