!> Benchmark of the Stokes solver (run through benchmarks/bench_stokes_fft.py).
!>
!> Usage: bench_stokes_fft N [kappa] [repeats] [mode] [shape] [transport] [precision]
!>   precision "double" (default) or "single": fft_precision of the solver (fold_stokes_fft);
!>     the FFT units stay the double transforms, and mode "cost" adds t_fft_sp, the hot
!>     single-precision FFT, and the CPU times t_iter_cpu, t_fft_cpu of this process.
!>   transport "auto" (default): serial FFTW on one rank (what fold_run and the Python
!>     extension use), FFTW-MPI slabs on several (spectrum left transposed: one
!>     all-to-all per transform); "mpi": FFTW-MPI slabs even on one rank;
!>     "natural": FFTW-MPI slabs with the spectrum in the real-space order (two
!>     all-to-alls per transform; the layout before the transposed one);
!>     "spectral": serial, with the CG operator in its spectral form (5 + 5 transforms)
!>     instead of the 3-D stencil form (3 + 3 and a stencil pass over the particles'
!>     voxels), to compare the two on one geometry.
!>   mode "cost" (default): wall time of one CG iteration in units of one real 3-D
!>     FFT of the same grid, two ways: against a "hot" FFT (r2c + c2r of one field,
!>     repeated; K's original unit) and against the FFTs as the iteration sees them
!>     (c2r then r2c over the ncg strain fields in turn). The floor is the number of
!>     FFTs per iteration, ffts: 6 in the 3-D stencil form (3 velocity components back,
!>     3 force components forward), 10 in the spectral form (5 traceless strain
!>     components back, 5 stress components forward). One line per repeat:
!>       BENCH n= ranks= t_fft= t_fft_seq= t_iter= ratio= ratio_seq= ffts= t_fft_sp= t_iter_cpu= t_fft_cpu=
!>   mode "fft": the time of one hot real 3-D FFT (r2c + c2r of one field, 50 pairs
!>     per repeat), wall and CPU seconds of this process; one line per repeat:
!>       FFT n= t_fft_wall= t_fft_cpu=
!>     (benchmarks/bench_stokes_step.py: the unit of its FFT-equivalents per step)
!>   mode "iters": CG iterations from a zero guess to tol 1e-6 (relative
!>     preconditioned residual); one line: ITERS n= kappa= iterations= residual=
!>   mode "batch": the ncg = 5 strain fields of an iteration transformed c2r + r2c
!>     one field at a time through the transport (t_sep) and as one FFTW-MPI plan of
!>     howmany = 5 interleaved fields (transposed spectrum; t_batch), which merges the
!>     5 all-to-alls of a pass into one of 5 times the size; seconds per field and
!>     transform, one line per repeat: BATCH n= ranks= t_sep= t_batch= ratio=
!>   mode "a2a": MPI_Alltoall alone, the parameters of the all-to-all model of
!>     docs/physics.md#parallel-scaling-of-the-slab-decomposition: t_small, one
!>     all-to-all of 8 bytes per rank pair (latency), and t_big, one of the blocks of a
!>     transposed transform (16 (n/2 + 1) n^2 / P^2 bytes per pair); bw = bytes each
!>     rank sends to the others / t_big; one line per repeat:
!>       A2A n= ranks= t_small= t_big= bytes_pair= bw=
!> Geometry (shape): "sphere" (default), radius N/8 voxels (0.8 % of the cell);
!> "ball", radius 0.4 N (27 % of the cell: the stencil pass over many voxels); or
!> "spheroid", a prolate
!> spheroid of semi-axes 1/4 and 1/32 (aspect ratio 8; 4 voxels per diameter at
!> N = 64) along (1, 1, 1)/sqrt(3); binary chi, in a unit cell on a sheared
!> (Lees-Edwards, offset 0.2) lattice, simple shear, FFTW_MEASURE plans, FFTW-MPI
!> slabs (mpirun -np P for P ranks).
program bench_stokes_fft
   use, intrinsic :: iso_c_binding
   use mpi_f08
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_fft_transport, only: fft_transport_t, FOLD_PLAN_MEASURE, FOLD_PLAN_ESTIMATE
   use fold_fft_mpi, only: fft_mpi_t, fft_mpi_create, fft_mpi_start
   use fold_fft_serial, only: fft_serial_t, fft_serial_create
   use fold_stokes_fft
   use fold_stokes_solver, only: FOLD_FFT_SINGLE
   use fold_grid, only: shear_lattice
   implicit none
   include 'fftw3-mpi.f03'
   class(fft_transport_t), allocatable :: fft
   type(fft_mpi_t), allocatable :: slab
   type(fft_serial_t), allocatable :: serial
   type(stokes_fft_t) :: s
   type(stokes_settings_t) :: set
   real(dp), allocatable :: chi(:, :, :)
   real(dp) :: G(3, 3), t0, t_fft, t_seq, t_it, x(3), c0, c1
   integer :: stat, rank, nranks, rep, nrep, i, j, k, c
   integer(ip) :: n
   character(len=msg_len) :: msg
   character(len=32) :: arg, mode, shape, transport, precision
   real(dp) :: t_fft_sp, c_fft, c_it
   real(dp) :: ax(3), along
   type(c_ptr) :: bmem, bfwd, bbwd
   real(dp), pointer :: rb(:)
   complex(dp), pointer :: cb(:)
   integer(c_intptr_t) :: balloc, bln0, bl0, bln1, bl1
   real(dp), allocatable :: sbuf(:), rbuf(:)
   integer :: nblk
   real(dp) :: t_small

   call MPI_Init()
   call fft_mpi_start()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   call MPI_Comm_size(MPI_COMM_WORLD, nranks)
   n = 64
   set%kappa = 1.0e3_dp
   nrep = 5
   mode = "cost"
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
   if (command_argument_count() >= 4) call get_command_argument(4, mode)
   shape = "sphere"
   if (command_argument_count() >= 5) call get_command_argument(5, shape)
   transport = "auto"
   if (command_argument_count() >= 6) call get_command_argument(6, transport)
   precision = "double"
   if (command_argument_count() >= 7) call get_command_argument(7, precision)
   ax = 1.0_dp/sqrt(3.0_dp)
   set%plan_effort = FOLD_PLAN_MEASURE
   ! the all-to-all timing makes no FFT: instant plans
   if (trim(mode) == "a2a") set%plan_effort = FOLD_PLAN_ESTIMATE
   set%warm_start = .false.
   if (trim(mode) == "iters") then
      set%tol = 1.0e-6_dp
      set%max_iter = 20000
   else
      set%tol = 1.0e-14_dp
      set%max_iter = 20
   end if
   if (trim(precision) == "single") then
      set%fft_precision = FOLD_FFT_SINGLE
      ! the smallest tolerance the setting accepts (cost: 20 iterations stop far above it)
      set%tol = max(set%tol, single_tol_min(int(n, i8)**3))
   end if
   if (nranks == 1 .and. trim(transport) /= "mpi") then
      allocate (serial)
      call fft_serial_create(serial, 3, [n, n, n], set%plan_effort, stat, msg)
      call check("fft_serial_create")
      call move_alloc(serial, fft)
   else
      allocate (slab)
      call fft_mpi_create(slab, MPI_COMM_WORLD, 3, [n, n, n], set%plan_effort, stat, msg, &
                          transposed=(trim(transport) /= "natural"))
      call check("fft_mpi_create")
      call move_alloc(slab, fft)
   end if
   call stokes_fft_init(s, fft, set, stat, msg)
   call check("stokes_fft_init")
   if (trim(transport) == "spectral") s%stencil_fraction_max = -1.0_dp
   call stokes_fft_set_lattice(s, shear_lattice([1.0_dp, 1.0_dp, 1.0_dp], 0.2_dp), stat, msg)
   call check("stokes_fft_set_lattice")
   allocate (chi(n, s%grid%nl(2), s%grid%nl(3)))
   do k = 1, s%grid%nl(3)
      do j = 1, s%grid%nl(2)
         do i = 1, n
            x = ([i, j, k + s%grid%off(3)] - 0.5_dp)/n - 0.5_dp
            if (trim(shape) == "spheroid") then
               along = dot_product(x, ax)
               chi(i, j, k) = merge(1.0_dp, 0.0_dp, (along/0.25_dp)**2 + sum((x - along*ax)**2)/0.03125_dp**2 < 1.0_dp)
            else if (trim(shape) == "ball") then
               chi(i, j, k) = merge(1.0_dp, 0.0_dp, norm2(x) < 0.4_dp)
            else
               chi(i, j, k) = merge(1.0_dp, 0.0_dp, norm2(x) < 0.125_dp)
            end if
         end do
      end do
   end do
   G = 0.0_dp
   G(1, 2) = 1.0_dp

   if (trim(mode) == "fft") then
      do rep = 1, nrep
         call round_trips(50, .false., t_fft, c_fft)
         if (rank == 0) print '(a,i0,a,es12.5,a,es12.5)', "FFT n=", n, " t_fft_wall=", t_fft, " t_fft_cpu=", c_fft
      end do
   else if (trim(mode) == "batch") then
      ! howmany = 5 interleaved fields (component fastest), transposed spectrum
      balloc = fftw_mpi_local_size_many_transposed(3, [int(n, c_intptr_t), int(n, c_intptr_t), int(n/2 + 1, c_intptr_t)], &
                                                   5_c_intptr_t, FFTW_MPI_DEFAULT_BLOCK, FFTW_MPI_DEFAULT_BLOCK, &
                                                   MPI_COMM_WORLD%MPI_VAL, bln0, bl0, bln1, bl1)
      bmem = fftw_alloc_complex(int(max(balloc, 1_c_intptr_t), c_size_t))
      call c_f_pointer(bmem, rb, [2*max(balloc, 1_c_intptr_t)])
      call c_f_pointer(bmem, cb, [max(balloc, 1_c_intptr_t)])
      bfwd = fftw_mpi_plan_many_dft_r2c(3, [int(n, c_intptr_t), int(n, c_intptr_t), int(n, c_intptr_t)], 5_c_intptr_t, &
                                        FFTW_MPI_DEFAULT_BLOCK, FFTW_MPI_DEFAULT_BLOCK, rb, cb, MPI_COMM_WORLD%MPI_VAL, &
                                        ior(FFTW_MEASURE, FFTW_MPI_TRANSPOSED_OUT))
      bbwd = fftw_mpi_plan_many_dft_c2r(3, [int(n, c_intptr_t), int(n, c_intptr_t), int(n, c_intptr_t)], 5_c_intptr_t, &
                                        FFTW_MPI_DEFAULT_BLOCK, FFTW_MPI_DEFAULT_BLOCK, cb, rb, MPI_COMM_WORLD%MPI_VAL, &
                                        ior(FFTW_MEASURE, FFTW_MPI_TRANSPOSED_IN))
      rb = 0.0_dp
      do rep = 1, nrep
         call MPI_Barrier(MPI_COMM_WORLD)
         t0 = MPI_Wtime()
         do i = 1, 10
            do c = 1, s%ncg
               call s%fft%c2r(s%work(s%cg_comp(c)))
               call s%fft%r2c(s%work(s%cg_comp(c)))
            end do
         end do
         call MPI_Barrier(MPI_COMM_WORLD)
         t_seq = (MPI_Wtime() - t0)/(20*s%ncg)
         t0 = MPI_Wtime()
         do i = 1, 10
            call fftw_mpi_execute_dft_c2r(bbwd, cb, rb)
            call fftw_mpi_execute_dft_r2c(bfwd, rb, cb)
         end do
         call MPI_Barrier(MPI_COMM_WORLD)
         t_fft = (MPI_Wtime() - t0)/(20*s%ncg)
         if (rank == 0) print '(a,i0,a,i0,a,es10.3,a,es10.3,a,f6.3)', "BATCH n=", n, " ranks=", nranks, &
            " t_sep=", t_seq, " t_batch=", t_fft, " ratio=", t_fft/t_seq
      end do
      call fftw_destroy_plan(bfwd)
      call fftw_destroy_plan(bbwd)
      call fftw_free(bmem)
   else if (trim(mode) == "a2a") then
      nblk = max(1, int(2*int(n/2 + 1, i8)*n*n/int(nranks, i8)**2))
      allocate (sbuf(nblk*nranks), rbuf(nblk*nranks))
      sbuf = 1.0_dp
      rbuf = 0.0_dp
      do rep = 1, nrep
         call MPI_Barrier(MPI_COMM_WORLD)
         t0 = MPI_Wtime()
         do i = 1, 1000
            call MPI_Alltoall(sbuf, 1, MPI_DOUBLE_PRECISION, rbuf, 1, MPI_DOUBLE_PRECISION, MPI_COMM_WORLD)
         end do
         t_small = (MPI_Wtime() - t0)/1000
         call MPI_Barrier(MPI_COMM_WORLD)
         t0 = MPI_Wtime()
         do i = 1, 20
            call MPI_Alltoall(sbuf, nblk, MPI_DOUBLE_PRECISION, rbuf, nblk, MPI_DOUBLE_PRECISION, MPI_COMM_WORLD)
         end do
         t_it = (MPI_Wtime() - t0)/20
         if (rank == 0) print '(a,i0,a,i0,a,es10.3,a,es10.3,a,i0,a,es10.3)', "A2A n=", n, " ranks=", nranks, &
            " t_small=", t_small, " t_big=", t_it, " bytes_pair=", 8*nblk, " bw=", &
            8.0_dp*nblk*(nranks - 1)/t_it
      end do
   else if (trim(mode) == "iters") then
      call stokes_fft_solve(s, chi, G, stat, msg)
      if (rank == 0) print '(a,i0,a,es9.2,a,a,a,i0,a,es10.3)', "ITERS n=", n, " kappa=", set%kappa, " shape=", &
         trim(shape), " iterations=", s%iterations, " residual=", s%residual
   else
      do rep = 1, nrep
         ! hot: one field forth and back, 10 times
         call round_trips(10, .false., t_fft, c_fft)
         t_fft_sp = 0.0_dp
         if (s%single) call round_trips(10, .true., t_fft_sp, c1)
         ! as in an iteration: c2r then r2c of each CG strain field in turn
         t0 = MPI_Wtime()
         do c = 1, s%ncg
            call s%fft%c2r(s%work(s%cg_comp(c)))
            call s%fft%r2c(s%work(s%cg_comp(c)))
         end do
         call MPI_Barrier(MPI_COMM_WORLD)
         t_seq = (MPI_Wtime() - t0)/(2*s%ncg)
         t0 = MPI_Wtime()
         call cpu_time(c0)
         call stokes_fft_solve(s, chi, G, stat, msg)
         call MPI_Barrier(MPI_COMM_WORLD)
         call cpu_time(c1)
         ! the solve also makes the viscosity, the rhs (1 FFT) and runs s%iterations iterations
         t_it = (MPI_Wtime() - t0 - t_fft)/max(s%iterations, 1)
         c_it = (c1 - c0 - c_fft)/max(s%iterations, 1)
         if (rank == 0) print '(a,i0,a,i0,a,es10.3,a,es10.3,a,es10.3,a,f6.2,a,f6.2,a,i0,3(a,es10.3))', "BENCH n=", n, &
            " ranks=", nranks, " t_fft=", t_fft, " t_fft_seq=", t_seq, " t_iter=", t_it, " ratio=", t_it/t_fft, &
            " ratio_seq=", t_it/t_seq, " ffts=", merge(6_ip, 2*s%ncg, s%stencil), " t_fft_sp=", t_fft_sp, " t_iter_cpu=", c_it, &
            " t_fft_cpu=", c_fft
      end do
   end if
   call stokes_fft_destroy(s)
   call fftw_mpi_cleanup()
   call MPI_Finalize()

contains

   !> Wall and CPU time per transform [s] of count forward-and-back transforms of one
   !> work field (single: the fftwf plans), between barriers.
   subroutine round_trips(count, single, wall, cpu)
      integer, intent(in) :: count
      logical, intent(in) :: single
      real(dp), intent(out) :: wall, cpu
      real(dp) :: t, c
      integer :: m
      call MPI_Barrier(MPI_COMM_WORLD)
      t = MPI_Wtime()
      call cpu_time(c)
      do m = 1, count
         call s%fft%transform(s%work(1), .true., single)
         call s%fft%transform(s%work(1), .false., single)
      end do
      call MPI_Barrier(MPI_COMM_WORLD)
      call cpu_time(cpu)
      wall = (MPI_Wtime() - t)/(2*count)
      cpu = (cpu - c)/(2*count)
   end subroutine round_trips

   subroutine check(what)
      character(len=*), intent(in) :: what
      if (stat /= 0 .and. stat /= 2) then
         if (rank == 0) print '(a)', "bench_stokes_fft: "//what//": "//trim(msg)
         call MPI_Abort(MPI_COMM_WORLD, 1)
      end if
   end subroutine check

end program bench_stokes_fft
