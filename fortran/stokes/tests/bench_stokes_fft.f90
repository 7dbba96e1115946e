!> Benchmark: cost of one CG iteration of the Stokes solver in units of one real
!> 3-D FFT of the same grid (the floor is 12: 6 c2r + 6 r2c per iteration), and
!> the wall time per iteration, serial or on MPI slabs (mpirun -np N).
!> Usage: bench_stokes_fft N [kappa] [repeats]; prints one line per measurement.
program bench_stokes_fft
   use, intrinsic :: iso_c_binding
   use mpi_f08
   use fold_kinds, only: dp, ip, msg_len
   use fold_fft_backend, only: fft_backend_t, fft_field_t, field_free, FOLD_PLAN_MEASURE
   use fold_fft_mpi, only: fft_mpi_t, fft_mpi_create
   use fold_stokes_fft
   use fold_grid, only: shear_lattice
   implicit none
   include 'fftw3-mpi.f03'
   class(fft_backend_t), allocatable :: fft
   type(fft_mpi_t), allocatable :: slab
   type(stokes_fft_t) :: s
   type(stokes_settings_t) :: set
   type(fft_field_t) :: f
   real(dp), allocatable :: chi(:, :, :)
   real(dp) :: G(3, 3), t0, t_fft, t_it, x(3)
   integer :: stat, rank, nranks, rep, nrep, i, j, k, niter
   integer(ip) :: n
   character(len=msg_len) :: msg
   character(len=32) :: arg

   call MPI_Init()
   call fftw_mpi_init()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   call MPI_Comm_size(MPI_COMM_WORLD, nranks)
   n = 64
   set%kappa = 1.0e3_dp
   nrep = 5
   if (command_argument_count() >= 1) then
      call get_command_argument(1, arg)
      read (arg, *) n
   end if
   if (command_argument_count() >= 2) then
      call get_command_argument(2, arg)
      read (arg, *) set%kappa
   end if
   if (command_argument_count() >= 3) then
      call get_command_argument(3, arg)
      read (arg, *) nrep
   end if
   set%plan_effort = FOLD_PLAN_MEASURE
   set%tol = 1.0e-14_dp
   niter = 20
   set%max_iter = niter
   set%warm_start = .false.
   allocate (slab)
   call fft_mpi_create(slab, MPI_COMM_WORLD, 3, [n, n, n], FOLD_PLAN_MEASURE, stat, msg)
   call move_alloc(slab, fft)
   call fft%alloc_field(f)
   f%r = 1.0_dp
   call stokes_fft_init(s, fft, set, stat, msg)
   call stokes_fft_set_lattice(s, shear_lattice([1.0_dp, 1.0_dp, 1.0_dp], 0.2_dp), stat, msg)
   ! a sphere of radius n/8 voxels
   allocate (chi(n, s%grid%nl(2), s%grid%nl(3)))
   do k = 1, s%grid%nl(3)
      do j = 1, s%grid%nl(2)
         do i = 1, n
            x = ([i, j, k + s%grid%off(3)] - 0.5_dp)/n - 0.5_dp
            chi(i, j, k) = merge(1.0_dp, 0.0_dp, norm2(x) < 0.125_dp)
         end do
      end do
   end do
   G = 0.0_dp
   G(1, 2) = 1.0_dp
   do rep = 1, nrep
      ! one real 3-D FFT: the mean of r2c and c2r of one field, 10 of each
      call MPI_Barrier(MPI_COMM_WORLD)
      t0 = MPI_Wtime()
      do i = 1, 10
         call s%fft%r2c(s%work(1))
         call s%fft%c2r(s%work(1))
      end do
      call MPI_Barrier(MPI_COMM_WORLD)
      t_fft = (MPI_Wtime() - t0)/20
      t0 = MPI_Wtime()
      call stokes_fft_solve(s, chi, G, stat, msg)
      call MPI_Barrier(MPI_COMM_WORLD)
      ! the solve also makes the rhs (1 FFT) and runs s%iterations iterations
      t_it = (MPI_Wtime() - t0 - t_fft)/max(s%iterations, 1)
      if (rank == 0) print '(a,i0,a,i0,a,es10.3,a,es10.3,a,f6.2)', "BENCH n=", n, " ranks=", nranks, &
         " t_fft=", t_fft, " t_iter=", t_it, " ratio=", t_it/t_fft
   end do
   call field_free(f)
   call stokes_fft_destroy(s)
   call fftw_mpi_cleanup()
   call MPI_Finalize()
end program bench_stokes_fft
