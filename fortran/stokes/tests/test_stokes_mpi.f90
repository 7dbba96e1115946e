!> The FFTW-MPI slab solver reproduces the serial one: same CG iterations, same
!> velocity field and rigid velocities to solver tolerance, in 3-D (slabs in z;
!> transposed spectrum, y distributed, and the natural one; an odd n2 that splits
!> unevenly) and 2-D (slabs in y), on a sheared (Lees-Edwards) lattice with spheres,
!> a spheroid and a fibre. Every rank also runs the serial solve on the whole grid
!> and compares its own slab. Before that, the spectral map of every transport
!> (nsl, soff, saxis of fold_fft_transport) is checked on one plane wave: its r2c
!> has one nonzero coefficient, N/2 at the wave's mode, and c2r gives N times it
!> back. Run with mpirun -np 1 or 2 (meson suite 'stokes').
program test_stokes_mpi
   use, intrinsic :: iso_c_binding
   use mpi_f08
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_fft_transport, only: fft_transport_t, fft_field_t, field_free
   use fold_fft_serial, only: fft_serial_t, fft_serial_create
   use fold_fft_mpi, only: fft_mpi_t, fft_mpi_create
   use fold_cell, only: cell_t, cell_init
   use fold_particles, only: particle_set_t, particles_init, FOLD_SPHERE, FOLD_SPHEROID, FOLD_FIBRE
   use fold_stokes_fft, only: stokes_settings_t
   use fold_stokes_solver, only: stokes_solver_t
   use fold_stokes_build, only: stokes_transport_solver
   use fold_stokes_step, only: stokes_context_t, stokes_record_t, stokes_context_init, stokes_context_attach, &
                               stokes_rigid_velocities, stokes_context_destroy
   use stokes_test_solver, only: mpi_test_start, mpi_test_end
   implicit none
   include 'fftw3-mpi.f03'
   integer :: rank, failures

   call mpi_test_start("test_stokes_mpi", rank, failures)
   call fftw_mpi_init()
   call check_spectral_map(3, [12, 10, 9], 0, failures)
   call check_spectral_map(3, [12, 10, 9], 1, failures)
   call check_spectral_map(3, [12, 10, 9], 2, failures)
   call check_spectral_map(2, [12, 10, 1], 0, failures)
   call check_spectral_map(2, [12, 10, 1], 1, failures)
   call compare(3, [32, 24, 20], .true., failures)
   call compare(3, [32, 24, 20], .false., failures)
   call compare(3, [16, 15, 12], .true., failures)
   call compare(2, [40, 30, 1], .true., failures)
   call fftw_mpi_cleanup()
   call mpi_test_end(failures)

contains

   !> One transport (kind 0 serial, 1 FFTW-MPI natural, 2 FFTW-MPI transposed) on the
   !> plane wave cos(2 pi (a x/nx + b y/ny + c z/nz)), a > 0: the half spectrum holds
   !> N/2 at m = (a, b, c) (read through the transport's map) and zero elsewhere.
   !> Round-off bound of an FFT of N values bounded by 1: log2(N) eps sum|f| <= log2(N) eps N
   !> per coefficient (and per value of the c2r of that spectrum); 4 times that is allowed.
   subroutine check_spectral_map(dim, n, kind, failures)
      integer(ip), intent(in) :: dim, n(3)
      integer, intent(in) :: kind
      integer, intent(inout) :: failures
      class(fft_transport_t), allocatable :: fft
      type(fft_serial_t), allocatable :: serial
      type(fft_mpi_t), allocatable :: slab
      type(fft_field_t) :: f
      integer(ip) :: i, j, k, g(3), m(3), wave(3)
      real(dp) :: ntot, thr, err(2), hits(1), expect, pi
      integer :: stat
      character(len=msg_len) :: msg

      pi = acos(-1.0_dp)
      wave = [2, 3, 1]
      if (dim == 2) wave(3) = 0
      if (kind == 0) then
         allocate (serial)
         call fft_serial_create(serial, dim, n, 0, stat, msg)
         call move_alloc(serial, fft)
      else
         allocate (slab)
         call fft_mpi_create(slab, MPI_COMM_WORLD, dim, n, 0, stat, msg, transposed=(kind == 2))
         call move_alloc(slab, fft)
      end if
      call check(stat == FOLD_OK, "spectral map: transport: "//trim(msg))
      if (stat /= FOLD_OK) return
      if (kind == 2 .and. dim == 3) call check(all(fft%saxis == [1, 3, 2]), "spectral map: 3-D MPI spectrum not transposed")
      call check(fft%nsl(1) == fft%nxh, "spectral map: first spectral extent is not nx/2 + 1")
      call fft%alloc_field(f)
      ntot = real(product(n(1:dim)), dp)
      thr = 4.0_dp*log(ntot)/log(2.0_dp)*epsilon(1.0_dp)*ntot
      do k = 1, fft%nl(3)
         do j = 1, fft%nl(2)
            do i = 1, n(1)
               g = [i, j, k] - 1 + fft%off
               f%r(i, j, k) = cos(2.0_dp*pi*sum(real(wave*g, dp)/real(n, dp)))
            end do
         end do
      end do
      call fft%r2c(f)
      err = 0.0_dp
      hits = 0.0_dp
      do k = 1, fft%nsl(3)
         do j = 1, fft%nsl(2)
            do i = 1, fft%nsl(1)
               m(fft%saxis) = [i, j, k] - 1 + fft%soff
               expect = 0.0_dp
               if (all(m == wave)) then
                  expect = 0.5_dp*ntot
                  hits = hits + 1.0_dp
               end if
               err(1) = max(err(1), abs(f%c(i, j, k) - expect))
            end do
         end do
      end do
      call fft%c2r(f)
      do k = 1, fft%nl(3)
         do j = 1, fft%nl(2)
            do i = 1, n(1)
               g = [i, j, k] - 1 + fft%off
               err(2) = max(err(2), abs(f%r(i, j, k) - ntot*cos(2.0_dp*pi*sum(real(wave*g, dp)/real(n, dp)))))
            end do
         end do
      end do
      if (kind /= 0) then
         call fft%max_all(err)
         call fft%sum_all(hits)
      end if
      call check(nint(hits(1)) == 1, "spectral map: the plane wave's mode is not found exactly once")
      call check(err(1) <= thr, "spectral map: r2c coefficients off the plane wave")
      call check(err(2) <= 2.0_dp*thr, "spectral map: c2r does not return N times the plane wave")
      call field_free(f)
      call fft%destroy()
   end subroutine check_spectral_map

   subroutine compare(dim, n, transposed, failures)
      integer(ip), intent(in) :: dim, n(3)
      !> 3-D: leave the distributed spectrum transposed (fft_mpi_create)
      logical, intent(in) :: transposed
      integer, intent(inout) :: failures
      real(dp), parameter :: thr = 1.0e-7_dp
      class(fft_transport_t), allocatable :: fft
      type(fft_mpi_t), allocatable :: slab
      class(stokes_solver_t), allocatable :: solver
      type(stokes_context_t) :: ctx_s, ctx_p
      type(stokes_settings_t) :: set
      type(stokes_record_t) :: rec_s, rec_p
      type(cell_t) :: cell
      type(particle_set_t) :: parts, parts_s
      real(dp) :: G(3, 3), lengths(3), du, umax, dv, red(2)
      integer :: stat, off, nl
      integer(ip) :: c
      real(dp), pointer, contiguous :: up(:, :, :), us(:, :, :)
      character(len=msg_len) :: msg

      G = 0.0_dp
      G(1, 2) = 1.0_dp
      lengths = [1.6_dp, 1.2_dp, 1.0_dp]
      call cell_init(cell, dim, lengths, .false., G, stat, msg)
      call check(stat == FOLD_OK, "cell_init: "//trim(msg))
      cell%shear_offset = 0.3_dp
      call particles_init(parts, dim, 3, stat, msg)
      parts%shape = [FOLD_SPHERE, FOLD_SPHEROID, FOLD_FIBRE]
      parts%radius = [0.15_dp, 0.1_dp, 0.08_dp]
      parts%length = [0.3_dp, 0.5_dp, 0.45_dp]
      if (dim == 3) then
         parts%x = reshape([0.3_dp, 0.3_dp, 0.3_dp, 1.0_dp, 0.8_dp, 0.55_dp, 0.9_dp, 0.15_dp, 0.8_dp], [3, 3])
         parts%p = reshape([1.0_dp, 0.0_dp, 0.0_dp, 0.6_dp, 0.64_dp, 0.48_dp, 0.0_dp, 0.6_dp, 0.8_dp], [3, 3])
      else
         parts%x = reshape([0.3_dp, 0.3_dp, 1.0_dp, 0.8_dp, 0.9_dp, 1.1_dp], [2, 3])
         parts%p = reshape([1.0_dp, 0.0_dp, 0.6_dp, 0.8_dp, 0.8_dp, -0.6_dp], [2, 3])
      end if
      parts_s = parts
      set%kappa = 1.0e3_dp
      set%tol = 1.0e-10_dp

      call stokes_context_init(ctx_s, set, dim, n, stat, msg)
      call check(stat == FOLD_OK, "stokes_context_init: "//trim(msg))
      call stokes_rigid_velocities(ctx_s, cell, parts_s, rec_s, stat, msg)
      call check(stat == FOLD_OK, "serial solve: "//trim(msg))

      allocate (slab)
      call fft_mpi_create(slab, MPI_COMM_WORLD, dim, n, 0, stat, msg, transposed=transposed)
      call check(stat == FOLD_OK, "fft_mpi_create: "//trim(msg))
      if (stat == FOLD_OK) call move_alloc(slab, fft)
      call stokes_transport_solver(set, fft, solver, stat, msg)
      call check(stat == FOLD_OK, "stokes_transport_solver: "//trim(msg))
      call stokes_context_attach(ctx_p, solver)
      call stokes_rigid_velocities(ctx_p, cell, parts, rec_p, stat, msg)
      call check(stat == FOLD_OK, "slab solve: "//trim(msg))

      ! this rank's slab of the distributed field against the same rows of the serial one
      off = ctx_p%solver%grid%off(dim)
      nl = ctx_p%solver%grid%nl(dim)
      du = 0.0_dp
      umax = 0.0_dp
      do c = 1, dim
         if (nl == 0) cycle
         up => ctx_p%solver%velocity_field(c)
         us => ctx_s%solver%velocity_field(c)
         if (dim == 3) then
            du = max(du, maxval(abs(up(1:n(1), :, :) - us(1:n(1), :, off + 1:off + nl))))
         else
            du = max(du, maxval(abs(up(1:n(1), :, 1) - us(1:n(1), off + 1:off + nl, 1))))
         end if
         umax = max(umax, maxval(abs(us(1:n(1), :, :))))
      end do
      red = [du, umax]
      call MPI_Allreduce(MPI_IN_PLACE, red, 2, MPI_DOUBLE_PRECISION, MPI_MAX, MPI_COMM_WORLD)
      dv = max(maxval(abs(parts%v - parts_s%v)), maxval(abs(parts%omega - parts_s%omega)))
      if (rank == 0) print '(a,i0,a,3(1x,i0),a,l1,a,i0,a,i0,a,es9.2,a,es9.2,a,es9.2)', "dim ", dim, " grid", n, &
         " transposed ", transposed .and. dim == 3, ": iterations serial ", &
         rec_s%iterations, ", slabs ", rec_p%iterations, "; max |du|/max|u| ", red(1)/red(2), &
         ", max |d(v, omega)| ", dv, ", d eta_eff ", abs(rec_p%bulk%eta_eff - rec_s%bulk%eta_eff)
      ! round-off (summation order of the dot products) may move the last few of
      ! hundreds of iterations across the tolerance, not more
      call check(abs(rec_p%iterations - rec_s%iterations) <= max(2, rec_s%iterations/20), "iteration counts differ")
      call check(red(1) <= thr*red(2), "velocity fields differ")
      call check(dv <= thr, "rigid velocities differ")
      call check(abs(rec_p%bulk%eta_eff - rec_s%bulk%eta_eff) <= thr, "effective viscosities differ")
      call stokes_context_destroy(ctx_s)
      call stokes_context_destroy(ctx_p)
   end subroutine compare

   subroutine check(ok, what)
      logical, intent(in) :: ok
      character(len=*), intent(in) :: what
      if (.not. ok) then
         failures = failures + 1
         if (rank == 0) print '(a,a)', "test_stokes_mpi: FAILED: ", what
      end if
   end subroutine check

end program test_stokes_mpi
