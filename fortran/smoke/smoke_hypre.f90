!> Stack smoke test: hypre Struct interface (built-in Fortran bindings).
!> 2-D Poisson -lap(u) = 1 on a 32 x 32*np grid split in y among ranks, zero
!> Dirichlet walls, PCG preconditioned by one PFMG V-cycle. Multigrid-
!> preconditioned CG must reach 1e-10 in a mesh-independent handful of
!> iterations; more than 30 means the stack is broken.
program smoke_hypre
   use mpi_f08
   implicit none
   integer, parameter :: nx = 32, ny = 32
   integer(8) :: grid, stencil, amat, bvec, xvec, solver, precond
   integer :: rank, nranks, ierr, i, iters
   integer :: ilower(2), iupper(2), offsets(2, 5), entries(5), bc_lo(2), bc_hi(2)
   double precision :: values(5*nx*ny), rhs(nx*ny), zeros(nx*ny), relres

   call MPI_Init()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   call MPI_Comm_size(MPI_COMM_WORLD, nranks)
   ilower = [0, rank*ny]
   iupper = [nx - 1, (rank + 1)*ny - 1]

   call HYPRE_StructGridCreate(MPI_COMM_WORLD%MPI_VAL, 2, grid, ierr)
   call HYPRE_StructGridSetExtents(grid, ilower, iupper, ierr)
   call HYPRE_StructGridAssemble(grid, ierr)

   offsets = reshape([0, 0, -1, 0, 1, 0, 0, -1, 0, 1], [2, 5])
   call HYPRE_StructStencilCreate(2, 5, stencil, ierr)
   do i = 1, 5
      call HYPRE_StructStencilSetElement(stencil, i - 1, offsets(:, i), ierr)
      entries(i) = i - 1
   end do

   call HYPRE_StructMatrixCreate(MPI_COMM_WORLD%MPI_VAL, grid, stencil, amat, ierr)
   call HYPRE_StructMatrixInitialize(amat, ierr)
   do i = 1, nx*ny
      values(5*(i - 1) + 1:5*i) = [4.0d0, -1.0d0, -1.0d0, -1.0d0, -1.0d0]
   end do
   call HYPRE_StructMatrixSetBoxValues(amat, ilower, iupper, 5, entries, values, ierr)
   ! zero Dirichlet walls: drop the stencil entries that reach outside the domain
   zeros = 0.0d0
   bc_lo = ilower; bc_hi = [ilower(1), iupper(2)]
   call HYPRE_StructMatrixSetBoxValues(amat, bc_lo, bc_hi, 1, [1], zeros, ierr)
   bc_lo = [iupper(1), ilower(2)]; bc_hi = iupper
   call HYPRE_StructMatrixSetBoxValues(amat, bc_lo, bc_hi, 1, [2], zeros, ierr)
   if (rank == 0) then
      bc_lo = ilower; bc_hi = [iupper(1), ilower(2)]
      call HYPRE_StructMatrixSetBoxValues(amat, bc_lo, bc_hi, 1, [3], zeros, ierr)
   end if
   if (rank == nranks - 1) then
      bc_lo = [ilower(1), iupper(2)]; bc_hi = iupper
      call HYPRE_StructMatrixSetBoxValues(amat, bc_lo, bc_hi, 1, [4], zeros, ierr)
   end if
   call HYPRE_StructMatrixAssemble(amat, ierr)

   rhs = 1.0d0/(nx*ny)
   call HYPRE_StructVectorCreate(MPI_COMM_WORLD%MPI_VAL, grid, bvec, ierr)
   call HYPRE_StructVectorCreate(MPI_COMM_WORLD%MPI_VAL, grid, xvec, ierr)
   call HYPRE_StructVectorInitialize(bvec, ierr)
   call HYPRE_StructVectorInitialize(xvec, ierr)
   call HYPRE_StructVectorSetBoxValues(bvec, ilower, iupper, rhs, ierr)
   call HYPRE_StructVectorSetBoxValues(xvec, ilower, iupper, zeros, ierr)
   call HYPRE_StructVectorAssemble(bvec, ierr)
   call HYPRE_StructVectorAssemble(xvec, ierr)

   call HYPRE_StructPCGCreate(MPI_COMM_WORLD%MPI_VAL, solver, ierr)
   call HYPRE_StructPCGSetTol(solver, 1.0d-10, ierr)
   call HYPRE_StructPCGSetMaxIter(solver, 100, ierr)
   call HYPRE_StructPCGSetTwoNorm(solver, 1, ierr)
   call HYPRE_StructPFMGCreate(MPI_COMM_WORLD%MPI_VAL, precond, ierr)
   call HYPRE_StructPFMGSetMaxIter(precond, 1, ierr)
   call HYPRE_StructPFMGSetTol(precond, 0.0d0, ierr)
   call HYPRE_StructPFMGSetZeroGuess(precond, ierr)
   ! precond_id 1 = PFMG in hypre's Fortran interface
   call HYPRE_StructPCGSetPrecond(solver, 1, precond, ierr)
   call HYPRE_StructPCGSetup(solver, amat, bvec, xvec, ierr)
   call HYPRE_StructPCGSolve(solver, amat, bvec, xvec, ierr)
   call HYPRE_StructPCGGetNumIterations(solver, iters, ierr)
   call HYPRE_StructPCGGetFinalRelative(solver, relres, ierr)

   if (rank == 0) print '(a,i0,a,es10.3,a,i0,a)', "smoke_hypre: PCG+PFMG ", iters, &
      " iterations, relative residual ", relres, " on ", nranks, " ranks"
   if (iters > 30 .or. relres > 1.0d-9 .or. relres /= relres) then
      if (rank == 0) print '(a)', "smoke_hypre: FAILED"
      call MPI_Abort(MPI_COMM_WORLD, 1)
   end if
   call HYPRE_StructPFMGDestroy(precond, ierr)
   call HYPRE_StructPCGDestroy(solver, ierr)
   call HYPRE_StructVectorDestroy(xvec, ierr)
   call HYPRE_StructVectorDestroy(bvec, ierr)
   call HYPRE_StructMatrixDestroy(amat, ierr)
   call HYPRE_StructStencilDestroy(stencil, ierr)
   call HYPRE_StructGridDestroy(grid, ierr)
   call MPI_Finalize()
end program smoke_hypre
