!> Benchmark of the hypre Stokes backend (run through benchmarks/bench_stokes_hypre.py).
!>
!> Usage: bench_stokes_hypre DIM N KAPPA REPEATS BACKEND WALLS
!>   BACKEND "hypre" or "fft"; WALLS 1 (no-slip walls at y = 0, Ly; hypre only) or 0
!>   (periodic, zero Lees-Edwards offset).
!> Scene: unit cell, N voxels per side, a sphere (2-D: disk) of radius N/8 voxels at
!> (0.45, 0.5, 0.55) and one of N/16 voxels at (0.8, 0.25, 0.3) (partial-volume chi),
!> simple shear, tol 1e-6, zero initial guess. Each repeat is one full solve
!> (matrix assembly, AMG setup and the Schur iterations for hypre); one line per repeat:
!>   SOLVE backend= dim= n= kappa= ranks= iterations= inner= residual= t_wall= t_cpu=
!> with t_wall the MPI_Wtime of the solve (max over ranks) and t_cpu the process CPU
!> time of the solve (max over ranks).
program bench_stokes_hypre
   use mpi_f08
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_NOT_CONVERGED
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t
   use fold_settings, only: FOLD_STOKES_HYPRE, FOLD_STOKES_FFT
   use fold_stokes_factory, only: stokes_solver_create
   use fold_stokes_hypre, only: stokes_hypre_t
   use fold_grid, only: shear_lattice
   use fold_particles, only: particle_set_t, particles_init, FOLD_SPHERE
   use fold_voxelise, only: voxel_set_t, voxelise
   implicit none
   integer :: rank, nranks, stat, rep, repeats, walls_arg
   integer(ip) :: dim, n, nn(3), inner
   real(dp) :: kappa, G(3, 3), t0, t1, c0, c1, red(2)
   character(len=32) :: arg, backend
   character(len=msg_len) :: msg
   type(stokes_settings_t) :: set
   class(stokes_solver_t), allocatable :: s
   type(particle_set_t) :: parts
   type(voxel_set_t) :: vox

   call MPI_Init()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   call MPI_Comm_size(MPI_COMM_WORLD, nranks)
   call get_command_argument(1, arg)
   read (arg, *) dim
   call get_command_argument(2, arg)
   read (arg, *) n
   call get_command_argument(3, arg)
   read (arg, *) kappa
   call get_command_argument(4, arg)
   read (arg, *) repeats
   call get_command_argument(5, backend)
   call get_command_argument(6, arg)
   read (arg, *) walls_arg
   set%kappa = kappa
   set%tol = 1.0e-6_dp
   set%max_iter = 2000
   set%warm_start = .false.
   set%walls = walls_arg == 1
   set%backend = merge(FOLD_STOKES_HYPRE, FOLD_STOKES_FFT, trim(backend) == "hypre")
   nn = [n, n, merge(n, 1_ip, dim == 3)]
   call stokes_solver_create(set, dim, nn, MPI_COMM_WORLD, s, stat, msg)
   if (stat /= FOLD_OK) call fail(msg)
   call s%set_lattice(shear_lattice([1.0_dp, 1.0_dp, 1.0_dp], 0.0_dp), stat, msg)
   if (stat /= FOLD_OK) call fail(msg)
   call particles_init(parts, dim, 2_ip, stat, msg)
   parts%shape = FOLD_SPHERE
   parts%radius = [0.125_dp, 0.0625_dp]
   parts%length = 2.0_dp*parts%radius
   if (dim == 3) then
      parts%x = reshape([0.45_dp, 0.5_dp, 0.55_dp, 0.8_dp, 0.25_dp, 0.3_dp], [3, 2])
   else
      parts%x = reshape([0.45_dp, 0.5_dp, 0.8_dp, 0.25_dp], [2, 2])
   end if
   parts%p = 0.0_dp
   parts%p(1, :) = 1.0_dp
   call voxelise(s%grid, parts, set%subsamples, set%fibre_ends, vox, stat, msg)
   if (stat /= FOLD_OK) call fail(msg)
   G = 0.0_dp
   G(1, 2) = 1.0_dp
   do rep = 1, repeats
      call MPI_Barrier(MPI_COMM_WORLD)
      t0 = MPI_Wtime()
      call cpu_time(c0)
      call s%solve(vox%chi, G, stat, msg)
      call cpu_time(c1)
      t1 = MPI_Wtime()
      if (stat /= FOLD_OK .and. stat /= FOLD_NOT_CONVERGED) call fail(msg)
      red = [t1 - t0, c1 - c0]
      call s%max_all(red)
      inner = 0
      select type (s)
      type is (stokes_hypre_t)
         inner = s%inner_iterations
      end select
      if (rank == 0) print '(a,a,a,i0,a,i0,a,es9.2,a,i0,a,i0,a,i0,a,es10.3,a,es10.3,a,es10.3)', &
         "SOLVE backend= ", trim(backend), " dim= ", dim, " n= ", n, " kappa= ", kappa, " ranks= ", nranks, &
         " iterations= ", s%iterations, " inner= ", inner, " residual= ", s%residual, " t_wall= ", red(1), &
         " t_cpu= ", red(2)
   end do
   call s%destroy()
   call MPI_Finalize()

contains

   subroutine fail(m)
      character(len=*), intent(in) :: m
      if (rank == 0) print '(a,a)', "bench_stokes_hypre: ", trim(m)
      call MPI_Abort(MPI_COMM_WORLD, 2)
   end subroutine fail

end program bench_stokes_hypre
