!> Single-precision transforms inside the double-precision CG (fold_stokes_fft,
!> fft_precision = FOLD_FFT_SINGLE) reach the tolerance and agree with the double
!> solve, through the factory (serial FFTW on one rank, FFTW-MPI slabs with the
!> transposed spectrum on two), in 3-D and 2-D, on a sheared lattice with a sphere
!> (disc) of partial-volume boundary, at kappa 10 and 1e3. Per case:
!>  * the double solve to tol 1e-9 and the single one to the smallest tolerance the
!>    setting accepts, tol_s = single_tol_min(N) = (2 log2 N + 4) u_s;
!>  * the true residual of the single solution, evaluated with the double operator
!>    (stokes_fft_true_residual), is <= 2 tol_s: the recursive residual is <= tol_s,
!>    and the gap between the two is <= tol_s by the bound's derivation (module header
!>    of fold_stokes_fft);
!>  * the two solutions agree in the energy norm within the bound that their true
!>    residuals give: the preconditioned operator M^-1 A has its spectrum in
!>    [eta_min/eta0, eta_max/eta0] = [kappa^-1/2, kappa^1/2] (eta0 the geometric mean),
!>    so ||e||_A <= kappa^1/4 ||A e||_M^-1 and ||x||_A >= kappa^-1/4 ||b||_M^-1, hence
!>    ||x_s - x_d||_A / ||x_d||_A <= kappa^1/2 (res_s + res_d);
!>  * a tolerance below tol_s, and an unknown precision code, are refused with
!>    FOLD_INPUT_ERROR and a message naming fft_precision.
!> Run with mpirun -np 1 or 2 (meson suite 'stokes').
program test_stokes_single
   use mpi_f08
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_grid, only: shear_lattice
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, FOLD_FFT_DOUBLE, FOLD_FFT_SINGLE
   use fold_stokes_factory, only: stokes_solver_create
   use fold_stokes_fft, only: stokes_fft_t, stokes_fft_true_residual, stokes_fft_apply, single_tol_min
   use stokes_test_check, only: check
   use stokes_test_solver, only: mpi_test_start, mpi_test_end
   implicit none
   integer :: rank, failures

   call mpi_test_start("test_stokes_single", rank, failures)
   call compare(3, [24, 24, 20], 10.0_dp, failures)
   call compare(3, [24, 24, 20], 1.0e3_dp, failures)
   call compare(2, [48, 40, 1], 1.0e3_dp, failures)
   call refusals(failures)
   call mpi_test_end(failures)

contains

   !> Settings of a case: harmonic mixing, rotated finite differences (the defaults).
   function settings(kappa, tol, precision) result(set)
      real(dp), intent(in) :: kappa, tol
      integer(ip), intent(in) :: precision
      type(stokes_settings_t) :: set
      set%kappa = kappa
      set%tol = tol
      set%max_iter = 5000
      set%warm_start = .false.
      set%fft_precision = precision
   end function settings

   !> A solver of the factory, seen as the FFT backend.
   subroutine make(set, dim, n, s, failures)
      type(stokes_settings_t), intent(in) :: set
      integer(ip), intent(in) :: dim, n(3)
      class(stokes_solver_t), allocatable, intent(out) :: s
      integer, intent(inout) :: failures
      integer :: stat
      character(len=msg_len) :: msg
      call stokes_solver_create(set, dim, n, MPI_COMM_WORLD, s, stat, msg)
      call check(stat == FOLD_OK, "create: "//trim(msg), failures)
      if (stat /= FOLD_OK) call MPI_Abort(MPI_COMM_WORLD, 1)
      call s%set_lattice(shear_lattice([1.0_dp, 1.0_dp, 1.0_dp], 0.2_dp), stat, msg)
      call check(stat == FOLD_OK, "set_lattice: "//trim(msg), failures)
   end subroutine make

   !> chi of a sphere (disc) of radius 0.3 at the cell centre on this rank's slab, with
   !> a linear partial-volume ramp one voxel wide.
   subroutine sphere_chi(dim, n, s, chi)
      integer(ip), intent(in) :: dim, n(3)
      class(stokes_solver_t), intent(in) :: s
      real(dp), allocatable, intent(out) :: chi(:, :, :)
      integer(ip) :: i, j, k, g(3)
      real(dp) :: x(3), d
      allocate (chi(n(1), s%grid%nl(2), s%grid%nl(3)))
      do k = 1, s%grid%nl(3)
         do j = 1, s%grid%nl(2)
            do i = 1, n(1)
               g = [i, j, k] + s%grid%off
               x = 0.0_dp
               x(1:dim) = (real(g(1:dim), dp) - 0.5_dp)/real(n(1:dim), dp) - 0.5_dp
               d = (norm2(x) - 0.3_dp)*real(n(1), dp)
               chi(i, j, k) = max(0.0_dp, min(1.0_dp, 0.5_dp - d))
            end do
         end do
      end do
   end subroutine sphere_chi

   subroutine compare(dim, n, kappa, failures)
      integer(ip), intent(in) :: dim, n(3)
      real(dp), intent(in) :: kappa
      integer, intent(inout) :: failures
      class(stokes_solver_t), allocatable :: sd, ss
      real(dp), allocatable :: chi(:, :, :)
      complex(dp), allocatable :: e(:, :, :, :), ae(:, :, :, :)
      real(dp) :: G(3, 3), tol_s, res_d, res_s, en(2), bound
      integer :: stat
      integer(ip) :: c, i
      character(len=msg_len) :: msg
      character(len=160) :: what

      G = 0.0_dp
      G(1, 2) = 1.0_dp
      tol_s = single_tol_min(product(int(n, i8)))
      write (what, '(i0,a,es8.1)') dim, "-D, kappa ", kappa
      call make(settings(kappa, 1.0e-9_dp, FOLD_FFT_DOUBLE), dim, n, sd, failures)
      call make(settings(kappa, tol_s, FOLD_FFT_SINGLE), dim, n, ss, failures)
      call sphere_chi(dim, n, sd, chi)
      call sd%solve(chi, G, stat, msg)
      call check(stat == FOLD_OK, trim(what)//": double solve: "//trim(msg), failures)
      call ss%solve(chi, G, stat, msg)
      call check(stat == FOLD_OK, trim(what)//": single solve: "//trim(msg), failures)
      select type (sd)
      type is (stokes_fft_t)
         select type (ss)
         type is (stokes_fft_t)
            call check(.not. sd%single .and. ss%single, trim(what)//": precision of the solvers", failures)
            e = ss%x - sd%x
            allocate (ae, mold=e)
            ! energies <e, A e> and <x_d, A x_d> over the half spectrum (Hermitian weights)
            call stokes_fft_apply(ss, e, ae)
            en(1) = 0.0_dp
            do c = 1, dim
               do i = 1, size(e, 1)
                  en(1) = en(1) + ss%wx(i)*sum(real(conjg(e(i, :, :, c))*ae(i, :, :, c), dp))
               end do
            end do
            call stokes_fft_apply(ss, sd%x, ae)
            en(2) = 0.0_dp
            do c = 1, dim
               do i = 1, size(e, 1)
                  en(2) = en(2) + ss%wx(i)*sum(real(conjg(sd%x(i, :, :, c))*ae(i, :, :, c), dp))
               end do
            end do
            call ss%sum_all(en)
            res_d = stokes_fft_true_residual(sd)
            res_s = stokes_fft_true_residual(ss)
            bound = sqrt(kappa)*(res_s + res_d)
            if (rank == 0) print '(a,a,i0,a,i0,a,es9.2,a,es9.2,a,es9.2,a,es9.2,a,es9.2)', trim(what), &
               ": iterations double ", sd%iterations, " single ", ss%iterations, ", tol_s ", tol_s, &
               ", true residual double ", res_d, " single ", res_s, ", ||x_s - x_d||_A/||x_d||_A ", &
               sqrt(max(en(1), 0.0_dp)/en(2)), " <= ", bound
            call check(res_s <= 2.0_dp*tol_s, trim(what)//": true residual of the single solve above 2 tol_s", &
                       failures)
            call check(en(2) > 0.0_dp .and. sqrt(max(en(1), 0.0_dp)/en(2)) <= bound, &
                       trim(what)//": single and double solutions differ beyond the residual bound", failures)
         end select
      end select
      call sd%destroy()
      call ss%destroy()
   end subroutine compare

   subroutine refusals(failures)
      integer, intent(inout) :: failures
      class(stokes_solver_t), allocatable :: s
      integer :: stat
      character(len=msg_len) :: msg
      real(dp) :: tol_s
      tol_s = single_tol_min(16_i8**3)
      call stokes_solver_create(settings(1.0e3_dp, 0.5_dp*tol_s, FOLD_FFT_SINGLE), 3, [16, 16, 16], &
                                MPI_COMM_WORLD, s, stat, msg)
      call check(stat == FOLD_INPUT_ERROR .and. index(msg, "fft_precision single needs tolerance >=") > 0 &
                 .and. .not. allocated(s), "a tolerance below tol_s is refused (got: "//trim(msg)//")", failures)
      call stokes_solver_create(settings(1.0e3_dp, tol_s, FOLD_FFT_SINGLE), 3, [16, 16, 16], &
                                MPI_COMM_WORLD, s, stat, msg)
      call check(stat == FOLD_OK, "tol_s itself is accepted (got: "//trim(msg)//")", failures)
      if (allocated(s)) call s%destroy()
      if (allocated(s)) deallocate (s)
      call stokes_solver_create(settings(1.0e3_dp, 1.0e-3_dp, 7_ip), 3, [16, 16, 16], MPI_COMM_WORLD, s, stat, msg)
      call check(stat == FOLD_INPUT_ERROR .and. index(msg, "fft_precision must be 0 (double) or 1 (single)") > 0, &
                 "an unknown precision code is refused (got: "//trim(msg)//")", failures)
   end subroutine refusals

end program test_stokes_single
