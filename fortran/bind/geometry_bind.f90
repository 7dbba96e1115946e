! Thin f2py layer over the geometry, particle and contact kernels: plain external
! subroutines with explicit-shape arguments (sizes hidden in geometry.pyf), each
! building the derived types from arrays and calling one library routine.
! pyfold/native/geometry.py checks shapes and turns stat/errmsg into exceptions.

!> Cell and particles from flat arguments (shared by every entry below).
module fold_geometry_bind_util
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_init, cell_set_time, cell_deforming
   use fold_particles, only: particle_set_t, particles_init
   implicit none
   private
   public :: make_cell, make_set
contains
   !> Shear cells take the Lees-Edwards offset as given; deforming cells are set to time t.
   subroutine make_cell(dim, lengths, walls, G, shear_offset, t, cell, stat, errmsg)
      integer(ip), intent(in) :: dim, walls
      real(dp), intent(in) :: lengths(3), G(3, 3), shear_offset, t
      type(cell_t), intent(out) :: cell
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call cell_init(cell, dim, lengths, walls /= 0, G, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (cell_deforming(cell)) then
         call cell_set_time(cell, t)
      else if (.not. cell%walls) then
         cell%shear_offset = shear_offset
      end if
   end subroutine make_cell

   !> Cell (make_cell) and a particle set of n particles at centres x with axes p, and the
   !> shapes, radii, lengths and shape factors given (the others keep particles_init's values).
   subroutine make_set(dim, n, lengths, walls, G, shear_offset, t, x, p, cell, parts, stat, errmsg, &
                       shape, radius, length, xi)
      integer(ip), intent(in) :: dim, n, walls
      real(dp), intent(in) :: lengths(3), G(3, 3), shear_offset, t, x(dim, n), p(dim, n)
      type(cell_t), intent(out) :: cell
      type(particle_set_t), intent(out) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip), intent(in), optional :: shape(n)
      real(dp), intent(in), optional :: radius(n), length(n), xi(n)
      call make_cell(dim, lengths, walls, G, shear_offset, t, cell, stat, errmsg)
      if (stat /= FOLD_OK) return
      call particles_init(parts, dim, n, stat, errmsg, x=x, p=p, shape=shape, radius=radius, length=length, xi=xi)
   end subroutine make_set
end module fold_geometry_bind_util

subroutine fold_geo_min_image(dim, n, lengths, walls, shear_offset, G, t, dx, dxo, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_min_image
   use fold_geometry_bind_util, only: make_cell
   implicit none
   integer(ip), intent(in) :: dim, n, walls
   real(dp), intent(in) :: lengths(3), shear_offset, G(3, 3), t, dx(dim, n)
   real(dp), intent(out) :: dxo(dim, n)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   integer(ip) :: k
   dxo = dx
   call make_cell(dim, lengths, walls, G, shear_offset, t, cell, stat, errmsg)
   if (stat /= FOLD_OK) return
   do k = 1, n
      call cell_min_image(cell, dxo(:, k))
   end do
end subroutine fold_geo_min_image

subroutine fold_geo_wrap(dim, n, lengths, walls, shear_offset, G, t, x, v, xo, vo, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_wrap
   use fold_geometry_bind_util, only: make_cell
   implicit none
   integer(ip), intent(in) :: dim, n, walls
   real(dp), intent(in) :: lengths(3), shear_offset, G(3, 3), t, x(dim, n), v(dim, n)
   real(dp), intent(out) :: xo(dim, n), vo(dim, n)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   integer(ip) :: k
   xo = x
   vo = v
   call make_cell(dim, lengths, walls, G, shear_offset, t, cell, stat, errmsg)
   if (stat /= FOLD_OK) return
   do k = 1, n
      call cell_wrap(cell, xo(:, k), vo(:, k))
   end do
end subroutine fold_geo_wrap

subroutine fold_geo_capsule_contact(dim, n, r, p1, h1, rad1, p2, h2, rad2, s, t, dist, normal)
   use fold_kinds, only: dp, ip
   use fold_segment, only: capsule_contact
   implicit none
   integer(ip), intent(in) :: dim, n
   real(dp), intent(in) :: r(dim, n), p1(dim, n), h1(n), rad1(n), p2(dim, n), h2(n), rad2(n)
   real(dp), intent(out) :: s(n), t(n), dist(n), normal(dim, n)
   integer(ip) :: k
   do k = 1, n
      call capsule_contact(r(:, k), p1(:, k), h1(k), rad1(k), p2(:, k), h2(k), rad2(k), &
                           dist(k), normal(:, k), s(k), t(k))
   end do
end subroutine fold_geo_capsule_contact

subroutine fold_geo_pairs(dim, n, maxpairs, lengths, walls, shear_offset, G, t, x, rc, use_cells, pairs, npairs, &
                          stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t
   use fold_cell_list, only: neighbour_pairs
   use fold_geometry_bind_util, only: make_cell
   implicit none
   integer(ip), intent(in) :: dim, n, maxpairs, walls, use_cells
   real(dp), intent(in) :: lengths(3), shear_offset, G(3, 3), t, x(dim, n), rc
   integer(ip), intent(out) :: pairs(2, maxpairs), npairs
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   pairs = 0
   npairs = 0
   call make_cell(dim, lengths, walls, G, shear_offset, t, cell, stat, errmsg)
   if (stat /= FOLD_OK) return
   call neighbour_pairs(cell, x, rc, use_cells /= 0, pairs, npairs, stat, errmsg)
end subroutine fold_geo_pairs

subroutine fold_geo_place(dim, n, lengths, walls, shear_offset, G, t, shape, radius, length, orient_mode, axis, &
                          alpha, seed, max_attempts, relax_sweeps, x, p, n_rsa, sweeps_used, stat, errmsg)
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t
   use fold_particles, only: particle_set_t
   use fold_placement, only: place_particles
   use fold_geometry_bind_util, only: make_set
   implicit none
   integer(ip), intent(in) :: dim, n, walls, shape(n), orient_mode(n), max_attempts, relax_sweeps
   real(dp), intent(in) :: lengths(3), shear_offset, G(3, 3), t, radius(n), length(n), axis(dim, n), alpha
   integer(i8), intent(in) :: seed
   real(dp), intent(out) :: x(dim, n), p(dim, n)
   integer(ip), intent(out) :: n_rsa, sweeps_used
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   type(particle_set_t) :: parts
   x = 0.0_dp
   p = 0.0_dp
   n_rsa = 0
   sweeps_used = 0
   call make_set(dim, n, lengths, walls, G, shear_offset, t, x, p, cell, parts, stat, errmsg, &
                 shape=shape, radius=radius, length=length)
   if (stat /= FOLD_OK) return
   call place_particles(cell, parts, alpha, seed, orient_mode, axis, max_attempts, relax_sweeps, &
                        n_rsa, sweeps_used, stat, errmsg)
   x = parts%x
   p = parts%p
end subroutine fold_geo_place

subroutine fold_geo_jeffery(dim, n, lengths, walls, G, x, p, xi, v, omega, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t
   use fold_particles, only: particle_set_t
   use fold_kinematics, only: jeffery_velocities
   use fold_geometry_bind_util, only: make_set
   implicit none
   integer(ip), intent(in) :: dim, n, walls
   real(dp), intent(in) :: lengths(3), G(3, 3), x(dim, n), p(dim, n), xi(n)
   real(dp), intent(out) :: v(dim, n), omega(3, n)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   type(particle_set_t) :: parts
   v = 0.0_dp
   omega = 0.0_dp
   call make_set(dim, n, lengths, walls, G, 0.0_dp, 0.0_dp, x, p, cell, parts, stat, errmsg, xi=xi)
   if (stat /= FOLD_OK) return
   call jeffery_velocities(cell, parts, stat, errmsg)
   v = parts%v
   omega = parts%omega
end subroutine fold_geo_jeffery

subroutine fold_geo_rigid_update(dim, n, x, p, v, omega, dt, xo, po)
   use fold_kinds, only: dp, ip
   use fold_kinematics, only: rotate_axis
   implicit none
   integer(ip), intent(in) :: dim, n
   real(dp), intent(in) :: x(dim, n), p(dim, n), v(dim, n), omega(3, n), dt
   real(dp), intent(out) :: xo(dim, n), po(dim, n)
   integer(ip) :: k
   ! same formula as fold_kinematics:rigid_update, without building a particle set
   do k = 1, n
      xo(:, k) = x(:, k) + v(:, k)*dt
      po(:, k) = rotate_axis(dim, p(:, k), omega(:, k), dt)
   end do
end subroutine fold_geo_rigid_update

subroutine fold_geo_jeffery_advance(dim, n, nout, lengths, walls, G, x, p, xi, dt, every, xhist, phist, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_cell, only: cell_t, cell_wrap, cell_advance
   use fold_particles, only: particle_set_t
   use fold_kinematics, only: jeffery_velocities, rigid_update
   use fold_geometry_bind_util, only: make_set
   implicit none
   integer(ip), intent(in) :: dim, n, nout, walls, every
   real(dp), intent(in) :: lengths(3), G(3, 3), x(dim, n), p(dim, n), xi(n), dt
   real(dp), intent(out) :: xhist(dim, n, nout), phist(dim, n, nout)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   type(particle_set_t) :: parts
   integer(ip) :: k, step, iout
   xhist = 0.0_dp
   phist = 0.0_dp
   if (every < 1 .or. nout < 1 .or. .not. (dt > 0.0_dp)) then
      stat = FOLD_INPUT_ERROR
      errmsg = "jeffery_advance: need every >= 1, nout >= 1, dt > 0"
      return
   end if
   call make_set(dim, n, lengths, walls, G, 0.0_dp, 0.0_dp, x, p, cell, parts, stat, errmsg, xi=xi)
   if (stat /= FOLD_OK) return
   xhist(:, :, 1) = x
   phist(:, :, 1) = p
   do iout = 2, nout
      do step = 1, every
         call jeffery_velocities(cell, parts, stat, errmsg)
         if (stat /= FOLD_OK) return
         call rigid_update(parts, dt)
         call cell_advance(cell, dt)
         do k = 1, n
            call cell_wrap(cell, parts%x(:, k), parts%v(:, k))
         end do
      end do
      xhist(:, :, iout) = parts%x
      phist(:, :, iout) = parts%p
   end do
end subroutine fold_geo_jeffery_advance

subroutine fold_geo_resolve_contacts(dim, n, lengths, walls, shear_offset, G, t, shape, radius, length, x, p, v, omega, &
                                     dt, mode, alpha, max_iter, on_cap, skin, first, last, vo, omegao, &
                                     n_corrections, iterations, min_gap, min_gap_over_alpha, pairs_left, &
                                     worst_gap, capped, push, list_builds, list_pairs, stat, errmsg)
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t
   use fold_particles, only: particle_set_t
   use fold_contacts, only: contact_config_t, contact_stats_t, resolve_contacts
   use fold_geometry_bind_util, only: make_set
   implicit none
   integer(ip), intent(in) :: dim, n, walls, shape(n), mode, max_iter, on_cap, first, last
   real(dp), intent(in) :: lengths(3), shear_offset, G(3, 3), t, radius(n), length(n), x(dim, n), p(dim, n)
   real(dp), intent(in) :: v(dim, n), omega(3, n), dt, alpha, skin
   real(dp), intent(out) :: vo(dim, n), omegao(3, n), min_gap, min_gap_over_alpha, worst_gap, push
   integer(i8), intent(out) :: n_corrections, pairs_left, list_pairs
   integer(ip), intent(out) :: iterations, capped, list_builds
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   type(particle_set_t) :: parts
   type(contact_config_t) :: cfg
   type(contact_stats_t) :: stats
   vo = v
   omegao = omega
   n_corrections = 0
   iterations = 0
   min_gap = 0.0_dp
   min_gap_over_alpha = 0.0_dp
   pairs_left = 0
   worst_gap = 0.0_dp
   capped = 0
   push = 0.0_dp
   list_builds = 0
   list_pairs = 0
   call make_set(dim, n, lengths, walls, G, shear_offset, t, x, p, cell, parts, stat, errmsg, &
                 shape=shape, radius=radius, length=length)
   if (stat /= FOLD_OK) return
   parts%v = v
   parts%omega = omega
   cfg%mode = mode
   cfg%alpha = alpha
   cfg%max_iter = max_iter
   cfg%on_cap = on_cap
   cfg%skin = skin
   call resolve_contacts(cell, parts, dt, cfg, stats, stat, errmsg, first, last)
   vo = parts%v
   omegao = parts%omega
   n_corrections = stats%n_corrections
   iterations = stats%iterations
   min_gap = stats%min_gap
   min_gap_over_alpha = stats%min_gap_over_alpha
   pairs_left = stats%pairs_left
   worst_gap = stats%worst_gap
   if (stats%capped) capped = 1
   push = stats%push
   list_builds = stats%list_builds
   list_pairs = stats%list_pairs
end subroutine fold_geo_resolve_contacts

subroutine fold_geo_cell_info(dim, lengths, walls, G, t, basis, thickness, origin, flow, period, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_lattice, cell_min_thickness, cell_set_time, cell_deforming
   use fold_geometry_bind_util, only: make_cell
   implicit none
   integer(ip), intent(in) :: dim, walls
   real(dp), intent(in) :: lengths(3), G(3, 3), t
   real(dp), intent(out) :: basis(3, 3), thickness(3), origin(3), period
   integer(ip), intent(out) :: flow
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   basis = 0.0_dp
   thickness = 0.0_dp
   origin = 0.0_dp
   period = 0.0_dp
   flow = 0
   call make_cell(dim, lengths, walls, G, 0.0_dp, 0.0_dp, cell, stat, errmsg)
   if (stat /= FOLD_OK) return
   ! shear cells too: the Lees-Edwards offset of time t
   call cell_set_time(cell, t)
   basis = cell_lattice(cell)
   thickness = cell%thickness
   if (.not. cell_deforming(cell)) thickness = cell_min_thickness(cell)
   origin = cell%origin
   flow = cell%flow
   period = cell%period
end subroutine fold_geo_cell_info

subroutine fold_geo_admissible_time(dim, lengths, walls, G, rc, dt, t_end, t_ok, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_admissible_time
   use fold_geometry_bind_util, only: make_cell
   implicit none
   integer(ip), intent(in) :: dim, walls
   real(dp), intent(in) :: lengths(3), G(3, 3), rc, dt, t_end
   real(dp), intent(out) :: t_ok
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(cell_t) :: cell
   t_ok = -1.0_dp
   call make_cell(dim, lengths, walls, G, 0.0_dp, 0.0_dp, cell, stat, errmsg)
   if (stat /= FOLD_OK) return
   t_ok = cell_admissible_time(cell, rc, dt, t_end)
end subroutine fold_geo_admissible_time

subroutine fold_geo_contact_range(n, shape, radius, length, alpha, skin, rc)
   use fold_kinds, only: dp, ip
   use fold_contacts, only: contact_search_range
   implicit none
   integer(ip), intent(in) :: n, shape(n)
   real(dp), intent(in) :: radius(n), length(n), alpha, skin
   real(dp), intent(out) :: rc
   rc = contact_search_range(shape, radius, length, alpha, skin)
end subroutine fold_geo_contact_range
