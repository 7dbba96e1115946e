!> Staggered-grid (MAC) Stokes solver with hypre: the second backend behind
!> fold_stokes_solver, for cells with walls (the Couette cell of fold_cell) and for
!> rectangular periodic cells.
!>
!> Problem (same convention as fold_stokes_fft): velocity u = G (x - c) + u~; the
!> disturbance u~ and the pressure p solve
!>     -div(2 eta eps(u~)) + grad p = div(2 (eta - eta_f) E),   div u~ = 0,
!> E = sym(G), eta = eta_f in the fluid and kappa eta_f in the solid, mixed in partially
!> covered voxels by the rule of the settings (FOLD_MIX_*, as in fold_stokes_fft).
!> (div(2 eta_f E) = 0 for a uniform eta_f, also discretely, so taking eta - eta_f
!> instead of eta only makes u~ = 0 exact for kappa = 1.) Periodic in x (and z);
!> in y either periodic or (settings%walls) no-slip walls at y = 0 and Ly, where
!> u~ = 0: the walls move at -/+U = -/+gamma_dot Ly/2, which the imposed flow already
!> satisfies. Fully periodic: the constant modes are removed (mean u~ = 0 as in the
!> FFT backend, mean p = 0). Only rectangular lattices: a Lees-Edwards offset would
!> need a sheared staggered grid, so set_lattice refuses it (use backend fft).
!>
!> Discretisation (Harlow & Welch 1965 MAC grid; variable-viscosity form of
!> Gerya & Yuen 2003, Phys. Earth Planet. Inter. 140:293): u_a on the faces normal
!> to a, p and the cell viscosity eta_c at cell (voxel) centres, the shear strains
!> eps_ab at the edges (2-D: nodes) normal to the (a, b) plane with the edge viscosity
!> eta_e = harmonic mean of the (up to) four cells around the edge. The operator is
!> built as the Hessian of the discrete dissipation
!>     J(u) = 1/2 sum_cells 2 eta_c sum_a eps_aa^2 + 1/2 sum_edges w_e 4 eta_e eps_ab^2,
!> so the velocity block A is symmetric positive (semi-)definite and the right-hand side
!> is the same sum with the stress 2 (eta - eta_f) E. The harmonic edge mean makes
!> a layered flow with layers aligned to cell faces exact (uniform shear stress: the
!> velocity jump across an edge is tau h/2 (1/eta_j + 1/eta_j+1) = tau h/eta_e).
!> Walls: the wall-normal velocity is zero on the wall faces (no unknowns there);
!> the tangential velocity has the mirror ghost u_ghost = -u, so the wall-edge strain
!> is u/(h/2); a wall edge has half a dual cell inside the cell (w_e = 1/2, 1
!> elsewhere) and its viscosity is the harmonic mean of the two cells it touches. Second order
!> for smooth viscosity (central differences on the staggered grid); at a viscosity
!> jump the usual O(h) of the fictitious-domain penalisation. The mirror ghost is exact
!> only for u linear in y: in the row next to a wall the truncation error is O(1),
!> eta u_yy/4 (the second difference (u(3h/2) - 3 u(h/2))/h^2 is 3/4 u_yy), an O(h)
!> error of the wall flux confined to one row, which moves the velocity by only O(h^2)
!> (supraconvergence of cell-centred Dirichlet walls); with eta varying along the wall
!> that row reaches second order only on fine grids (docs/physics.md, hypre section;
!> the operator and this truncation are checked in fortran/stokes/tests/test_stokes_hypre.f90, order3).
!>
!> Solver (Schur-complement CG, "Uzawa-CG"; Elman, Silvester & Wathen 2014, Finite
!> Elements and Fast Iterative Solvers, ch. 4 and 9): with the divergence D and
!> A u - D^T p = f, D u = 0, the pressure solves S p = -D A^-1 f with
!> S = D A^-1 D^T, symmetric positive definite on mean-zero pressures. Outer PCG on S,
!> preconditioned by the inverse of the viscosity-scaled pressure mass matrix,
!> M^-1 r = eta_c r (S ~ 1/eta cell by cell, the standard choice for variable
!> viscosity: Grinevich & Olshanskii 2009, SIAM J. Sci. Comput. 31:1569). Each outer
!> iteration applies A^-1 once: PCG on A (hypre ParCSR, built with the IJ interface)
!> preconditioned by one V-cycle of unknown-based systems BoomerAMG (the dim velocity
!> components interleaved face by face, so each component coarsens on its own:
!> 2-4x fewer inner iterations than scalar AMG, measured with
!> benchmarks/bench_stokes_hypre.py; in 3-D with aggressive coarsening on the first
!> level), to a relative residual tol_inner =
!> min(1e-2 tol, 1e-8), so that the inexact inner solves do not limit the outer
!> iteration. An assembled matrix (IJ) and algebraic multigrid rather than SysPFMG
!> on a semi-structured grid: the staggered components and the harmonic edge
!> viscosities give a coupled, strongly varying system for which AMG needs no
!> geometric setup, and the same code serves 2-D, 3-D, walls and periodicity.
!> Fully periodic A is singular (constant u_a); one face of each component is pinned
!> to 0 (row and column of the identity, scaled), which keeps the consistent system's
!> solution up to the constant, then the mean is removed. Stopping: the relative
!> preconditioned residual sqrt(<r, eta_c r> / <b, eta_c b>) of the pressure
!> equation, r = -D u (a relative divergence) <= settings%tol; iterations, residual and history
!> as in fold_stokes_fft; FOLD_NOT_CONVERGED keeps the last iterate. No warm start
!> (settings%warm_start is ignored): every solve starts from p = 0.
!>
!> Decomposition: slabs along the last axis (y in 2-D, z in 3-D) of near-equal
!> thickness; s%grid holds this rank's slab, so fold_voxelise, fold_rigid_fit and
!> fold_stress work unchanged. Fields are stored with one halo layer on each side
!> of that axis (filled by MPI_Sendrecv with the periodic neighbours); a rank owns the
!> faces at the lower side of its cells (the wall-normal faces on the wall y = 0 are
!> identity rows, so that every cell carries dim rows).
module fold_stokes_hypre
   use mpi_f08, only: MPI_Comm, MPI_Comm_rank, MPI_Comm_size, MPI_Allreduce, MPI_Sendrecv, MPI_IN_PLACE, &
                      MPI_DOUBLE_PRECISION, MPI_SUM, MPI_MAX, MPI_STATUS_IGNORE
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NUMERICAL
   use fold_grid, only: grid_t, grid_init, grid_set_lattice
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t
   use fold_penalty, only: solve_begin, penalty_viscosity, solve_verdict
   implicit none
   private

   !> hypre's object type code of a ParCSR matrix/vector (HYPRE.h)
   integer, parameter :: HYPRE_PARCSR = 5555
   !> Largest number of distinct columns of a velocity row (3-D: 3 + 4 x 4 = 19)
   integer, parameter :: max_cols = 32

   type, extends(stokes_solver_t), public :: stokes_hypre_t
      type(MPI_Comm) :: comm
      integer :: rank = 0, nranks = 1
      !> Decomposed axis (dim) and the bounds of the halo arrays per axis
      integer(ip) :: ax = 3, lb(3) = 0, ub(3) = 0
      !> Grid spacing per axis [m]
      real(dp) :: hs(3) = 1.0_dp
      !> Slab of every rank along ax: offset and thickness (0:nranks-1)
      integer(ip), allocatable :: r_off(:), r_nl(:)
      !> Face range of component a on rank r: first index and count per axis (3, dim, 0:nranks-1)
      integer(ip), allocatable :: clo(:, :, :), ccnt(:, :, :)
      !> Global number of the first face of component a on rank r (dim, 0:nranks-1)
      integer, allocatable :: cbase(:, :)
      !> This rank's rows [ilower, iupper] and their global numbers
      integer :: ilower = 0, iupper = -1, nloc = 0
      integer, allocatable :: rows(:)
      real(dp), allocatable :: buf(:)
      !> Face fields (lb1:ub1, lb2:ub2, lb3:ub3, dim): u~, the inner solution, the force
      real(dp), allocatable :: uf(:, :, :, :), wf(:, :, :, :), ff(:, :, :, :)
      !> Cell fields (.., 1): viscosity, pressure and the CG vectors of the Schur iteration
      real(dp), allocatable :: etac(:, :, :, :), pc(:, :, :, :), rc(:, :, :, :), zc(:, :, :, :), &
                               dc(:, :, :, :), qc(:, :, :, :)
      !> Outputs at the voxel centres (1:nx, 1:nl2, 1:nl3[, c])
      real(dp), pointer, contiguous :: vel(:, :, :, :) => null(), eps(:, :, :, :) => null(), eta(:, :, :) => null()
      !> hypre handles: IJ matrix and vectors, ParCSR objects, PCG and BoomerAMG
      integer(8) :: hA = 0, hb = 0, hx = 0, parA = 0, parb = 0, parx = 0, pcg = 0, amg = 0
      logical :: have_matrix = .false., have_vectors = .false., have_solver = .false., lattice_set = .false.
      !> Inner (velocity) PCG iterations of the last solve, summed
      integer(ip) :: inner_iterations = 0
      !> Relative tolerance of the inner solves
      real(dp) :: tol_inner = 1.0e-8_dp
   contains
      procedure :: set_lattice => hypre_set_lattice
      procedure :: solve => hypre_solve
      procedure :: compute_velocity => hypre_velocity
      procedure :: compute_strain => hypre_strain
      procedure :: velocity_field => hypre_velocity_field
      procedure :: strain_field => hypre_strain_field
      procedure :: viscosity_field => hypre_viscosity_field
      procedure :: sum_all => hypre_sum_all
      procedure :: max_all => hypre_max_all
      procedure :: destroy => hypre_destroy
   end type stokes_hypre_t

   !> Terms of a strain component as a linear form in face values
   type :: terms_t
      integer :: n = 0
      integer(ip) :: comp(4) = 0, f(3, 4) = 0
      real(dp) :: w(4) = 0.0_dp
      !> Dual-cell weight of the location (1/2 on a wall edge)
      real(dp) :: omega = 1.0_dp
   end type terms_t

   public :: stokes_hypre_new

contains

   !> A hypre solver on a dim-dimensional grid of n voxels shared by the ranks of comm
   !> (slabs along the last axis), settings checked by the caller (fold_stokes_factory).
   !> Collective. On failure solver stays unallocated.
   subroutine stokes_hypre_new(set, dim, n, comm, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer(ip), intent(in) :: dim, n(3)
      type(MPI_Comm), intent(in) :: comm
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(stokes_hypre_t), allocatable :: s
      integer(ip) :: nl(3), off(3), r, a, d, q, nax
      integer :: ierr, tot

      errmsg = ""
      stat = FOLD_INPUT_ERROR
      if (dim /= 2 .and. dim /= 3) then
         write (errmsg, '(a,i0)') "hypre: dim must be 2 or 3, got ", dim
         return
      end if
      allocate (s)
      s%set = set
      s%comm = comm
      call MPI_Comm_rank(comm, s%rank)
      call MPI_Comm_size(comm, s%nranks)
      s%dim = dim
      s%ax = dim
      nax = n(dim)
      if (nax < s%nranks .or. any(n(1:dim) < 2)) then
         write (errmsg, '(a,3(1x,i0),a,i0,a)') "hypre: grid counts must be >= 2 and the last one >= the ranks, got", &
            n(1:dim), " on ", s%nranks, " ranks"
         return
      end if
      allocate (s%r_off(0:s%nranks - 1), s%r_nl(0:s%nranks - 1))
      q = 0
      do r = 0, s%nranks - 1
         s%r_nl(r) = nax/s%nranks + merge(1, 0, r < mod(nax, s%nranks))
         s%r_off(r) = q
         q = q + s%r_nl(r)
      end do
      nl = 1
      off = 0
      nl(1:dim) = n(1:dim)
      nl(dim) = s%r_nl(s%rank)
      off(dim) = s%r_off(s%rank)
      call grid_init(s%grid, dim, n, nl, off, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (dim == 3) then
         s%nc = 6
         s%ci = [1, 2, 3, 1, 1, 2]
         s%cj = [1, 2, 3, 2, 3, 3]
      else
         s%nc = 3
         s%ci = [1, 2, 1, 0, 0, 0]
         s%cj = [1, 2, 2, 0, 0, 0]
      end if
      ! halo arrays: full range on the other axes, one layer each side of the slab
      s%lb = 0
      s%ub = 0
      do d = 1, dim
         s%lb(d) = 0
         s%ub(d) = s%grid%n(d) - 1
      end do
      s%lb(s%ax) = off(s%ax) - 1
      s%ub(s%ax) = off(s%ax) + nl(s%ax)
      ! rows of every rank: the dim faces at the lower side of each of its cells,
      ! interleaved by component (BoomerAMG's unknown-based systems AMG needs
      ! point-wise ordering); the wall-normal faces at y = 0 are identity rows
      allocate (s%clo(3, dim, 0:s%nranks - 1), s%ccnt(3, dim, 0:s%nranks - 1), s%cbase(dim, 0:s%nranks - 1))
      tot = 0
      do r = 0, s%nranks - 1
         do a = 1, dim
            s%clo(:, a, r) = 0
            s%ccnt(:, a, r) = 1
            do d = 1, dim
               if (d == s%ax) then
                  s%clo(d, a, r) = s%r_off(r)
                  s%ccnt(d, a, r) = s%r_nl(r)
               else
                  s%ccnt(d, a, r) = s%grid%n(d)
               end if
            end do
            s%cbase(a, r) = tot
         end do
         tot = tot + int(dim*product(s%ccnt(:, 1, r)))
      end do
      s%ilower = s%cbase(1, s%rank)
      s%nloc = int(dim*product(s%ccnt(:, 1, s%rank)))
      s%iupper = s%ilower + s%nloc - 1
      allocate (s%rows(s%nloc), s%buf(s%nloc))
      do r = 1, s%nloc
         s%rows(r) = s%ilower + r - 1
      end do
      allocate (s%uf(s%lb(1):s%ub(1), s%lb(2):s%ub(2), s%lb(3):s%ub(3), dim))
      allocate (s%wf, s%ff, mold=s%uf)
      allocate (s%etac(s%lb(1):s%ub(1), s%lb(2):s%ub(2), s%lb(3):s%ub(3), 1))
      allocate (s%pc, s%rc, s%zc, s%dc, s%qc, mold=s%etac)
      s%uf = 0.0_dp
      s%wf = 0.0_dp
      s%ff = 0.0_dp
      s%etac = set%eta_f
      s%pc = 0.0_dp
      s%rc = 0.0_dp
      s%zc = 0.0_dp
      s%dc = 0.0_dp
      s%qc = 0.0_dp
      allocate (s%vel(nl(1), nl(2), nl(3), dim), s%eps(nl(1), nl(2), nl(3), s%nc), s%eta(nl(1), nl(2), nl(3)))
      s%vel = 0.0_dp
      s%eps = 0.0_dp
      s%eta = set%eta_f
      allocate (s%history(0:set%max_iter))
      s%history = 0.0_dp
      s%tol_inner = min(1.0e-2_dp*set%tol, 1.0e-8_dp)
      ! right-hand side and solution vectors of the velocity solves, made once
      call HYPRE_IJVectorCreate(s%comm%MPI_VAL, s%ilower, s%iupper, s%hb, ierr)
      call HYPRE_IJVectorSetObjectType(s%hb, HYPRE_PARCSR, ierr)
      call HYPRE_IJVectorInitialize(s%hb, ierr)
      call HYPRE_IJVectorCreate(s%comm%MPI_VAL, s%ilower, s%iupper, s%hx, ierr)
      call HYPRE_IJVectorSetObjectType(s%hx, HYPRE_PARCSR, ierr)
      call HYPRE_IJVectorInitialize(s%hx, ierr)
      s%buf = 0.0_dp
      call HYPRE_IJVectorSetValues(s%hb, s%nloc, s%rows, s%buf, ierr)
      call HYPRE_IJVectorSetValues(s%hx, s%nloc, s%rows, s%buf, ierr)
      call HYPRE_IJVectorAssemble(s%hb, ierr)
      call HYPRE_IJVectorAssemble(s%hx, ierr)
      call HYPRE_IJVectorGetObject(s%hb, s%parb, ierr)
      call HYPRE_IJVectorGetObject(s%hx, s%parx, ierr)
      s%have_vectors = .true.
      stat = FOLD_OK
      errmsg = ""
      call move_alloc(s, solver)
   end subroutine stokes_hypre_new

   !> Set the lattice; only a rectangular one (zero shear offset) is accepted.
   subroutine hypre_set_lattice(s, A, stat, errmsg)
      class(stokes_hypre_t), intent(inout) :: s
      real(dp), intent(in) :: A(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: d, e
      do d = 1, s%dim
         do e = 1, s%dim
            if (d /= e .and. A(d, e) /= 0.0_dp) then
               stat = FOLD_INPUT_ERROR
               write (errmsg, '(a,i0,a,i0,a,es10.3,a)') "hypre: the staggered grid is rectangular; a sheared "// &
                  "periodic lattice needs backend fft (got A(", d, ",", e, ") = ", A(d, e), ")"
               return
            end if
         end do
      end do
      call grid_set_lattice(s%grid, A, stat, errmsg)
      if (stat /= FOLD_OK) return
      do d = 1, s%dim
         s%hs(d) = s%grid%A(d, d)/real(s%grid%n(d), dp)
      end do
      s%lattice_set = .true.
   end subroutine hypre_set_lattice

   !> Solve for u~ given chi on the local slab and G (module header).
   subroutine hypre_solve(s, chi, G, stat, errmsg)
      class(stokes_hypre_t), intent(inout) :: s
      real(dp), intent(in) :: chi(:, :, :)
      real(dp), intent(in) :: G(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: i, j, k, it, nin
      real(dp) :: red(2), bb, rz, rz_new, alpha, beta, dq, fmax
      integer :: st

      call solve_begin(s, s%lattice_set, chi, G, "hypre", stat, errmsg)
      if (stat /= FOLD_OK) return
      ! viscosity at the cell centres (settings' mixing rule, as fold_stokes_fft)
      call penalty_viscosity(s%set, chi, s%eta)
      do k = 1, s%grid%nl(3)
         do j = 1, s%grid%nl(2)
            do i = 1, s%grid%n(1)
               s%etac(i - 1, s%grid%off(2) + j - 1, s%grid%off(3) + k - 1, 1) = s%eta(i, j, k)
            end do
         end do
      end do
      call halo(s, s%etac)
      s%history = 0.0_dp
      s%iterations = 0
      s%residual = 0.0_dp
      s%inner_iterations = 0
      s%uf = 0.0_dp
      s%pc = 0.0_dp

      call assemble(s, fmax)
      red = [fmax, 0.0_dp]
      call s%max_all(red)
      if (.not. (red(1) > 0.0_dp)) then
         ! uniform viscosity (or E = 0): u~ = 0 exactly
         return
      end if
      call setup_inner(s)

      ! u = A^-1 f, r = -D u (the Schur residual at p = 0)
      call inner_solve(s, s%ff, s%uf, nin, st)
      s%inner_iterations = s%inner_iterations + nin
      call divergence(s, s%uf, s%rc)
      s%rc = -s%rc
      call project_mean(s, s%rc)
      call precondition(s)
      rz = cell_dot(s, s%rc, s%zc)
      bb = rz
      if (.not. (bb > 0.0_dp)) then
         ! A^-1 f is already divergence-free: no pressure needed
         call finish(s)
         return
      end if
      s%dc = s%zc
      s%residual = 1.0_dp
      s%history(0) = 1.0_dp
      it = 0
      do while (s%residual > s%set%tol .and. it < s%set%max_iter)
         it = it + 1
         ! w = A^-1 D^T d, q = S d = D w
         call gradient_t(s, s%dc, s%ff)
         call inner_solve(s, s%ff, s%wf, nin, st)
         s%inner_iterations = s%inner_iterations + nin
         call divergence(s, s%wf, s%qc)
         dq = cell_dot(s, s%dc, s%qc)
         if (.not. (dq > 0.0_dp)) then
            stat = FOLD_NUMERICAL
            write (errmsg, '(a,i0,a,es10.3)') "hypre: Schur CG breakdown at iteration ", it, ", <d, S d> = ", dq
            s%iterations = it
            call finish(s)
            return
         end if
         alpha = rz/dq
         s%pc = s%pc + alpha*s%dc
         s%uf = s%uf + alpha*s%wf
         s%rc = s%rc - alpha*s%qc
         call project_mean(s, s%rc)
         call precondition(s)
         rz_new = cell_dot(s, s%rc, s%zc)
         beta = rz_new/rz
         rz = rz_new
         s%dc = s%zc + beta*s%dc
         s%residual = sqrt(max(rz, 0.0_dp)/bb)
         s%history(it) = s%residual
      end do
      s%iterations = it
      call finish(s)
      call solve_verdict(s%set, "hypre", "Schur CG", it, s%residual, stat, errmsg)
   end subroutine hypre_solve

   !> Fully periodic: remove the mean of each velocity component; fill the halos.
   subroutine finish(s)
      type(stokes_hypre_t), intent(inout) :: s
      integer(ip) :: a
      real(dp) :: m(3)
      if (.not. s%set%walls) then
         m = 0.0_dp
         do a = 1, s%dim
            m(a) = sum(s%uf(:, own_lo(s, 2):own_hi(s, 2), own_lo(s, 3):own_hi(s, 3), a))
         end do
         call s%sum_all(m)
         m = m/real(s%grid%n(1)*s%grid%n(2)*s%grid%n(3), dp)
         do a = 1, s%dim
            s%uf(:, :, :, a) = s%uf(:, :, :, a) - m(a)
         end do
      end if
      call halo(s, s%uf)
   end subroutine finish

   !> u~ at the voxel centres: mean of the two faces of each component.
   subroutine hypre_velocity(s)
      class(stokes_hypre_t), intent(inout) :: s
      integer(ip) :: i, j, k, a, c(3), e(3)
      do k = 1, s%grid%nl(3)
         do j = 1, s%grid%nl(2)
            do i = 1, s%grid%n(1)
               c = [i - 1, s%grid%off(2) + j - 1, s%grid%off(3) + k - 1]
               do a = 1, s%dim
                  e = 0
                  e(a) = 1
                  s%vel(i, j, k, a) = 0.5_dp*(fval(s, s%uf, a, c) + fval(s, s%uf, a, c + e))
               end do
            end do
         end do
      end do
   end subroutine hypre_velocity

   !> Strain of u~ at the voxel centres: normal components from the two faces, shear
   !> components the mean of the four edge values around the centre.
   subroutine hypre_strain(s)
      class(stokes_hypre_t), intent(inout) :: s
      integer(ip) :: i, j, k, c(3), a, b, m, sa, sb, e(3)
      real(dp) :: v
      type(terms_t) :: t
      do k = 1, s%grid%nl(3)
         do j = 1, s%grid%nl(2)
            do i = 1, s%grid%n(1)
               c = [i - 1, s%grid%off(2) + j - 1, s%grid%off(3) + k - 1]
               do m = 1, s%nc
                  a = s%ci(m)
                  b = s%cj(m)
                  if (a == b) then
                     call cell_terms(s, a, c, t)
                     s%eps(i, j, k, m) = apply_terms(s, s%uf, t)
                  else
                     v = 0.0_dp
                     do sa = 0, 1
                        do sb = 0, 1
                           e = c
                           e(a) = e(a) + sa
                           e(b) = e(b) + sb
                           call edge_terms(s, a, b, e, t)
                           v = v + apply_terms(s, s%uf, t)
                        end do
                     end do
                     s%eps(i, j, k, m) = 0.25_dp*v
                  end if
               end do
            end do
         end do
      end do
   end subroutine hypre_strain

   function hypre_velocity_field(s, c) result(f)
      class(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: c
      real(dp), pointer, contiguous :: f(:, :, :)
      f => s%vel(:, :, :, c)
   end function hypre_velocity_field

   function hypre_strain_field(s, c) result(f)
      class(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: c
      real(dp), pointer, contiguous :: f(:, :, :)
      f => s%eps(:, :, :, c)
   end function hypre_strain_field

   function hypre_viscosity_field(s) result(f)
      class(stokes_hypre_t), intent(in) :: s
      real(dp), pointer, contiguous :: f(:, :, :)
      f => s%eta
   end function hypre_viscosity_field

   subroutine hypre_sum_all(s, x)
      class(stokes_hypre_t), intent(in) :: s
      real(dp), intent(inout) :: x(:)
      if (s%nranks > 1) call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, MPI_SUM, s%comm)
   end subroutine hypre_sum_all

   subroutine hypre_max_all(s, x)
      class(stokes_hypre_t), intent(in) :: s
      real(dp), intent(inout) :: x(:)
      if (s%nranks > 1) call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, MPI_MAX, s%comm)
   end subroutine hypre_max_all

   !> Release the hypre objects and the storage.
   subroutine hypre_destroy(s)
      class(stokes_hypre_t), intent(inout) :: s
      integer :: ierr
      call free_inner(s)
      if (s%have_matrix) then
         call HYPRE_IJMatrixDestroy(s%hA, ierr)
         s%have_matrix = .false.
      end if
      if (s%have_vectors) then
         call HYPRE_IJVectorDestroy(s%hb, ierr)
         call HYPRE_IJVectorDestroy(s%hx, ierr)
         s%have_vectors = .false.
      end if
      if (associated(s%vel)) deallocate (s%vel)
      if (associated(s%eps)) deallocate (s%eps)
      if (associated(s%eta)) deallocate (s%eta)
      if (allocated(s%uf)) deallocate (s%uf, s%wf, s%ff)
      if (allocated(s%etac)) deallocate (s%etac, s%pc, s%rc, s%zc, s%dc, s%qc)
      if (allocated(s%rows)) deallocate (s%rows, s%buf)
      if (allocated(s%r_off)) deallocate (s%r_off, s%r_nl)
      if (allocated(s%clo)) deallocate (s%clo, s%ccnt, s%cbase)
      if (allocated(s%history)) deallocate (s%history)
      s%lattice_set = .false.
   end subroutine hypre_destroy

   ! ------------------------------------------------------------------ grid helpers

   !> First and last own index along axis d (cells and faces)
   pure function own_lo(s, d) result(v)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: d
      integer(ip) :: v
      v = s%grid%off(d)
   end function own_lo

   pure function own_hi(s, d) result(v)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: d
      integer(ip) :: v
      v = s%grid%off(d) + s%grid%nl(d) - 1
   end function own_hi

   !> A wall-normal face on a wall (u~ = 0 there, not an unknown)
   pure logical function wall_face(s, a, f)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, f(3)
      wall_face = s%set%walls .and. a == 2 .and. (f(2) <= 0 .or. f(2) >= s%grid%n(2))
   end function wall_face

   !> Index f wrapped onto the periodic axes other than the decomposed one (which
   !> stays inside the halo) [array index of the halo arrays]
   pure function wrap(s, f) result(q)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: f(3)
      integer(ip) :: q(3), d
      q = f
      do d = 1, s%dim
         if (d /= s%ax) q(d) = modulo(f(d), s%grid%n(d))
      end do
      if (s%dim == 2) q(3) = 0
   end function wrap

   !> Face value of component a at face index f (0 on a wall face)
   function fval(s, x, a, f) result(v)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(in) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer(ip), intent(in) :: a, f(3)
      real(dp) :: v
      integer(ip) :: q(3)
      if (wall_face(s, a, f)) then
         v = 0.0_dp
         return
      end if
      q = wrap(s, f)
      v = x(q(1), q(2), q(3), a)
   end function fval

   !> Cell value at cell index c (wrapped; inside the halo along the decomposed axis)
   function cval(s, x, c) result(v)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(in) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer(ip), intent(in) :: c(3)
      real(dp) :: v
      integer(ip) :: q(3)
      q = wrap(s, c)
      v = x(q(1), q(2), q(3), 1)
   end function cval

   !> Global unknown number of face (a, f); -1 on a wall face
   function gid(s, a, f) result(g)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, f(3)
      integer :: g
      if (wall_face(s, a, f)) then
         g = -1
      else
         g = row_of(s, a, f)
      end if
   end function gid

   !> Row of face (a, f) (also of a wall face, whose row is the identity)
   function row_of(s, a, f) result(g)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, f(3)
      integer :: g
      integer(ip) :: q(3), d, r
      q = 0
      do d = 1, s%dim
         q(d) = modulo(f(d), s%grid%n(d))
      end do
      r = 0
      do while (r < s%nranks - 1)
         if (q(s%ax) < s%r_off(r) + s%r_nl(r)) exit
         r = r + 1
      end do
      g = s%cbase(1, r) + int(s%dim*((q(1) - s%clo(1, 1, r)) + s%ccnt(1, 1, r)*((q(2) - s%clo(2, 1, r)) &
                                                                              + s%ccnt(2, 1, r)*(q(3) - s%clo(3, 1, r)))) + a - 1)
   end function row_of

   !> Fully periodic: the face pinned to zero to remove the constant mode of component a
   pure logical function pinned(s, a, f)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, f(3)
      integer(ip) :: d
      pinned = .false.
      if (s%set%walls) return
      do d = 1, s%dim
         if (modulo(f(d), s%grid%n(d)) /= 0) return
      end do
      pinned = a >= 1
   end function pinned

   !> eps_aa at cell c: (u_a(c + e_a) - u_a(c)) / h_a
   subroutine cell_terms(s, a, c, t)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, c(3)
      type(terms_t), intent(out) :: t
      integer(ip) :: e(3)
      e = 0
      e(a) = 1
      t%n = 2
      t%comp(1:2) = a
      t%f(:, 1) = c + e
      t%w(1) = 1.0_dp/s%hs(a)
      t%f(:, 2) = c
      t%w(2) = -1.0_dp/s%hs(a)
      t%omega = 1.0_dp
   end subroutine cell_terms

   !> eps_ab (a /= b) at edge e (the corner of cell e normal to the (a, b) plane):
   !> (d u_a/d x_b + d u_b/d x_a)/2; on a wall edge the mirror ghost of the tangential
   !> component and half the dual cell (module header).
   subroutine edge_terms(s, a, b, e, t)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, b, e(3)
      type(terms_t), intent(out) :: t
      integer(ip) :: ea(3), eb(3), r
      ea = 0
      ea(a) = 1
      eb = 0
      eb(b) = 1
      t%omega = 1.0_dp
      if (s%set%walls .and. (a == 2 .or. b == 2) .and. (e(2) == 0 .or. e(2) == s%grid%n(2))) then
         t%omega = 0.5_dp
         r = merge(b, a, a == 2)
         t%n = 1
         t%comp(1) = r
         if (e(2) == 0) then
            t%f(:, 1) = e
            t%w(1) = 1.0_dp/s%hs(2)
         else
            t%f(:, 1) = e - [0, 1, 0]
            t%w(1) = -1.0_dp/s%hs(2)
         end if
         return
      end if
      t%n = 4
      t%comp = [a, a, b, b]
      t%f(:, 1) = e
      t%w(1) = 0.5_dp/s%hs(b)
      t%f(:, 2) = e - eb
      t%w(2) = -0.5_dp/s%hs(b)
      t%f(:, 3) = e
      t%w(3) = 0.5_dp/s%hs(a)
      t%f(:, 4) = e - ea
      t%w(4) = -0.5_dp/s%hs(a)
   end subroutine edge_terms

   !> Harmonic mean of the cell viscosities around edge e of the (a, b) plane
   !> (cells outside the walls left out)
   function edge_eta(s, a, b, e) result(v)
      type(stokes_hypre_t), intent(in) :: s
      integer(ip), intent(in) :: a, b, e(3)
      real(dp) :: v, acc
      integer(ip) :: sa, sb, c(3), cnt
      acc = 0.0_dp
      cnt = 0
      do sa = 0, 1
         do sb = 0, 1
            c = e
            c(a) = c(a) - sa
            c(b) = c(b) - sb
            if (s%set%walls .and. (c(2) < 0 .or. c(2) >= s%grid%n(2))) cycle
            acc = acc + 1.0_dp/cval(s, s%etac, c)
            cnt = cnt + 1
         end do
      end do
      v = real(cnt, dp)/acc
   end function edge_eta

   function apply_terms(s, x, t) result(v)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(in) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      type(terms_t), intent(in) :: t
      real(dp) :: v
      integer :: m
      v = 0.0_dp
      do m = 1, t%n
         v = v + t%w(m)*fval(s, x, t%comp(m), t%f(:, m))
      end do
   end function apply_terms

   ! ------------------------------------------------------------------ assembly

   !> Build the velocity matrix A (rows of this rank) into a new IJ matrix and the
   !> force f into s%ff; fmax = max |f| on this rank.
   subroutine assemble(s, fmax)
      type(stokes_hypre_t), intent(inout) :: s
      real(dp), intent(out) :: fmax
      integer(ip) :: a, b, i, j, k, f(3), ea(3), eb(3), l
      integer :: ierr, ncol, row, cols(max_cols)
      real(dp) :: vals(max_cols), diag, rhs, et
      type(terms_t) :: t

      if (s%have_matrix) call HYPRE_IJMatrixDestroy(s%hA, ierr)
      call HYPRE_IJMatrixCreate(s%comm%MPI_VAL, s%ilower, s%iupper, s%ilower, s%iupper, s%hA, ierr)
      call HYPRE_IJMatrixSetObjectType(s%hA, HYPRE_PARCSR, ierr)
      call HYPRE_IJMatrixInitialize(s%hA, ierr)
      s%have_matrix = .true.
      s%ff = 0.0_dp
      fmax = 0.0_dp
      do k = own_lo(s, 3), own_hi(s, 3)
         do j = own_lo(s, 2), own_hi(s, 2)
            do i = 0, s%grid%n(1) - 1
               do a = 1, s%dim
                  ea = 0
                  ea(a) = 1
                  f = [i, j, k]
                  row = row_of(s, a, f)
                  if (wall_face(s, a, f)) then
                     ! identity row of a wall face, scaled like its neighbours
                     diag = 2.0_dp*cval(s, s%etac, f)/s%hs(a)**2
                     call HYPRE_IJMatrixSetValues(s%hA, 1, [1], [row], [row], [diag], ierr)
                     s%ff(f(1), f(2), f(3), a) = 0.0_dp
                     cycle
                  end if
                  ncol = 0
                  rhs = 0.0_dp
                  ! normal strain of the cells on either side
                  do l = 0, 1
                     call cell_terms(s, a, f - l*ea, t)
                     et = cval(s, s%etac, f - l*ea)
                     call add_location(s, t, row, 2.0_dp*et, 2.0_dp*(et - s%set%eta_f)*s%E(a, a), &
                                       ncol, cols, vals, rhs)
                  end do
                  ! shear strain of the edges at f and f + e_b, b /= a
                  do b = 1, s%dim
                     if (b == a) cycle
                     eb = 0
                     eb(b) = 1
                     do l = 0, 1
                        call edge_terms(s, a, b, f + l*eb, t)
                        et = edge_eta(s, a, b, f + l*eb)
                        call add_location(s, t, row, 4.0_dp*et, 4.0_dp*(et - s%set%eta_f)*s%E(a, b), &
                                          ncol, cols, vals, rhs)
                     end do
                  end do
                  if (pinned(s, a, f)) then
                     ! identity row and column, scaled like the diagonal
                     diag = 0.0_dp
                     do l = 1, ncol
                        if (cols(l) == row) diag = vals(l)
                     end do
                     ncol = 1
                     cols(1) = row
                     vals(1) = diag
                     rhs = 0.0_dp
                  end if
                  call HYPRE_IJMatrixSetValues(s%hA, 1, [ncol], [row], cols(1:ncol), vals(1:ncol), ierr)
                  s%ff(f(1), f(2), f(3), a) = rhs
                  fmax = max(fmax, abs(rhs))
               end do
            end do
         end do
      end do
      call HYPRE_IJMatrixAssemble(s%hA, ierr)
      call HYPRE_IJMatrixGetObject(s%hA, s%parA, ierr)
   end subroutine assemble

   !> Add one stress location (strain terms t, stiffness alpha = 2 or 4 eta, prestress
   !> weight sig = alpha_0 E with the eta - eta_f stress) to the row of unknown row.
   subroutine add_location(s, t, row, alpha, sig, ncol, cols, vals, rhs)
      type(stokes_hypre_t), intent(in) :: s
      type(terms_t), intent(in) :: t
      integer, intent(in) :: row
      real(dp), intent(in) :: alpha, sig
      integer, intent(inout) :: ncol, cols(:)
      real(dp), intent(inout) :: vals(:), rhs
      integer :: m, l, g(4)
      real(dp) :: wd
      logical :: found
      wd = 0.0_dp
      do m = 1, t%n
         g(m) = gid(s, t%comp(m), t%f(:, m))
         if (g(m) == row) wd = wd + t%w(m)
      end do
      if (wd == 0.0_dp) return
      ! rhs: -omega sigma^0 : W (the multiplicity 2 of the shear pair is in sig)
      rhs = rhs - t%omega*sig*wd
      do m = 1, t%n
         if (g(m) < 0) cycle
         if (g(m) /= row .and. pinned(s, t%comp(m), t%f(:, m))) cycle
         found = .false.
         do l = 1, ncol
            if (cols(l) == g(m)) then
               vals(l) = vals(l) + t%omega*alpha*wd*t%w(m)
               found = .true.
               exit
            end if
         end do
         if (.not. found) then
            ncol = ncol + 1
            cols(ncol) = g(m)
            vals(ncol) = t%omega*alpha*wd*t%w(m)
         end if
      end do
   end subroutine add_location

   ! ------------------------------------------------------------------ inner solver

   !> PCG + one BoomerAMG V-cycle on the current matrix.
   subroutine setup_inner(s)
      type(stokes_hypre_t), intent(inout) :: s
      integer :: ierr
      call free_inner(s)
      call HYPRE_ParCSRPCGCreate(s%comm%MPI_VAL, s%pcg, ierr)
      call HYPRE_ParCSRPCGSetTol(s%pcg, s%tol_inner, ierr)
      call HYPRE_ParCSRPCGSetMaxIter(s%pcg, 1000, ierr)
      call HYPRE_ParCSRPCGSetTwoNorm(s%pcg, 1, ierr)
      call HYPRE_ParCSRPCGSetPrintLevel(s%pcg, 0, ierr)
      call HYPRE_BoomerAMGCreate(s%amg, ierr)
      call HYPRE_BoomerAMGSetMaxIter(s%amg, 1, ierr)
      call HYPRE_BoomerAMGSetTol(s%amg, 0.0_dp, ierr)
      call HYPRE_BoomerAMGSetPrintLevel(s%amg, 0, ierr)
      ! HMIS coarsening, symmetric hybrid Gauss-Seidel: a symmetric V-cycle for PCG
      call HYPRE_BoomerAMGSetCoarsenType(s%amg, 10, ierr)
      call HYPRE_BoomerAMGSetRelaxType(s%amg, 6, ierr)
      call HYPRE_BoomerAMGSetNumSweeps(s%amg, 1, ierr)
      ! unknown-based systems AMG: the dim interleaved velocity components coarsen separately
      call HYPRE_BoomerAMGSetNumFunctions(s%amg, int(s%dim), ierr)
      call HYPRE_BoomerAMGSetStrongThrshld(s%amg, 0.25_dp, ierr)
      ! 3-D: aggressive coarsening on the finest level cuts the operator complexity;
      ! measured (benchmarks/bench_stokes_hypre.py, 24^3, walls, kappa 1e3) 2.9x less
      ! CPU per solve than standard HMIS with threshold 0.5 despite 1.3x more inner
      ! iterations; in 2-D it costs more than it saves (1.1x slower at 128^2)
      if (s%dim == 3) call HYPRE_BoomerAMGSetAggNumLevels(s%amg, 1, ierr)
      ! precond_id 2 = BoomerAMG in hypre's Fortran interface
      call HYPRE_ParCSRPCGSetPrecond(s%pcg, 2, s%amg, ierr)
      call pack_faces(s, s%ff, s%hb)
      s%buf = 0.0_dp
      call HYPRE_IJVectorSetValues(s%hx, s%nloc, s%rows, s%buf, ierr)
      call HYPRE_IJVectorAssemble(s%hx, ierr)
      call HYPRE_ParCSRPCGSetup(s%pcg, s%parA, s%parb, s%parx, ierr)
      s%have_solver = .true.
   end subroutine setup_inner

   !> Destroy the inner PCG and its BoomerAMG preconditioner, if made.
   subroutine free_inner(s)
      class(stokes_hypre_t), intent(inout) :: s
      integer :: ierr
      if (.not. s%have_solver) return
      call HYPRE_ParCSRPCGDestroy(s%pcg, ierr)
      call HYPRE_BoomerAMGDestroy(s%amg, ierr)
      s%have_solver = .false.
   end subroutine free_inner

   !> y = A^-1 x (to tol_inner), halos of y filled.
   subroutine inner_solve(s, x, y, iters, stat)
      type(stokes_hypre_t), intent(inout) :: s
      real(dp), intent(in) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      real(dp), intent(inout) :: y(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer(ip), intent(out) :: iters
      integer, intent(out) :: stat
      integer :: ierr, n
      call pack_faces(s, x, s%hb)
      s%buf = 0.0_dp
      call HYPRE_IJVectorSetValues(s%hx, s%nloc, s%rows, s%buf, ierr)
      call HYPRE_IJVectorAssemble(s%hx, ierr)
      call HYPRE_ParCSRPCGSolve(s%pcg, s%parA, s%parb, s%parx, ierr)
      call HYPRE_ParCSRPCGGetNumIterations(s%pcg, n, ierr)
      iters = n
      stat = ierr
      call HYPRE_IJVectorGetValues(s%hx, s%nloc, s%rows, s%buf, ierr)
      call unpack_faces(s, y)
      call halo(s, y)
   end subroutine inner_solve

   !> Own face values of x (row order: face component fastest, then x, y, z) into the
   !> IJ vector v, through s%buf.
   subroutine pack_faces(s, x, v)
      type(stokes_hypre_t), intent(inout) :: s
      real(dp), intent(in) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer(8), intent(in) :: v
      integer :: ierr
      associate (n1 => s%grid%n(1), nl => s%grid%nl, j0 => own_lo(s, 2), j1 => own_hi(s, 2), &
                 k0 => own_lo(s, 3), k1 => own_hi(s, 3))
         s%buf(1:s%nloc) = reshape(reshape(x(0:n1 - 1, j0:j1, k0:k1, 1:s%dim), [s%dim, n1, nl(2), nl(3)], &
                                           order=[2, 3, 4, 1]), [s%nloc])
      end associate
      call HYPRE_IJVectorSetValues(v, s%nloc, s%rows, s%buf, ierr)
      call HYPRE_IJVectorAssemble(v, ierr)
   end subroutine pack_faces

   !> s%buf (row order, as pack_faces) into the own faces of y.
   subroutine unpack_faces(s, y)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(inout) :: y(s%lb(1):, s%lb(2):, s%lb(3):, :)
      associate (n1 => s%grid%n(1), nl => s%grid%nl, j0 => own_lo(s, 2), j1 => own_hi(s, 2), &
                 k0 => own_lo(s, 3), k1 => own_hi(s, 3))
         y(0:n1 - 1, j0:j1, k0:k1, 1:s%dim) = reshape(s%buf(1:s%nloc), [n1, nl(2), nl(3), s%dim], order=[4, 1, 2, 3])
      end associate
   end subroutine unpack_faces

   ! ------------------------------------------------------------------ Schur iteration

   !> dv = D u on the own cells (u with filled halos)
   subroutine divergence(s, u, dv)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(in) :: u(s%lb(1):, s%lb(2):, s%lb(3):, :)
      real(dp), intent(inout) :: dv(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer(ip) :: i, j, k, a, c(3), e(3)
      real(dp) :: v
      do k = own_lo(s, 3), own_hi(s, 3)
         do j = own_lo(s, 2), own_hi(s, 2)
            do i = 0, s%grid%n(1) - 1
               c = [i, j, k]
               v = 0.0_dp
               do a = 1, s%dim
                  e = 0
                  e(a) = 1
                  v = v + (fval(s, u, a, c + e) - fval(s, u, a, c))/s%hs(a)
               end do
               dv(i, j, k, 1) = v
            end do
         end do
      end do
   end subroutine divergence

   !> g = D^T p on the own unknown faces: (p(f - e_a) - p(f)) / h_a (0 on the pinned ones)
   subroutine gradient_t(s, p, g)
      type(stokes_hypre_t), intent(inout) :: s
      real(dp), intent(inout) :: p(s%lb(1):, s%lb(2):, s%lb(3):, :)
      real(dp), intent(inout) :: g(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer(ip) :: a, i, j, k, f(3), e(3)
      call halo(s, p)
      g = 0.0_dp
      do k = own_lo(s, 3), own_hi(s, 3)
         do j = own_lo(s, 2), own_hi(s, 2)
            do i = 0, s%grid%n(1) - 1
               do a = 1, s%dim
                  e = 0
                  e(a) = 1
                  f = [i, j, k]
                  if (pinned(s, a, f) .or. wall_face(s, a, f)) cycle
                  g(i, j, k, a) = (cval(s, p, f - e) - cval(s, p, f))/s%hs(a)
               end do
            end do
         end do
      end do
   end subroutine gradient_t

   !> z = eta_c r, mean removed
   subroutine precondition(s)
      type(stokes_hypre_t), intent(inout) :: s
      s%zc = s%etac*s%rc
      call project_mean(s, s%zc)
   end subroutine precondition

   subroutine project_mean(s, x)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(inout) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      real(dp) :: m(1)
      m(1) = sum(x(:, own_lo(s, 2):own_hi(s, 2), own_lo(s, 3):own_hi(s, 3), 1))
      call s%sum_all(m)
      m(1) = m(1)/real(s%grid%n(1)*s%grid%n(2)*s%grid%n(3), dp)
      x(:, own_lo(s, 2):own_hi(s, 2), own_lo(s, 3):own_hi(s, 3), 1) = &
         x(:, own_lo(s, 2):own_hi(s, 2), own_lo(s, 3):own_hi(s, 3), 1) - m(1)
   end subroutine project_mean

   function cell_dot(s, x, y) result(v)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(in) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :), y(s%lb(1):, s%lb(2):, s%lb(3):, :)
      real(dp) :: v, red(1)
      red(1) = sum(x(:, own_lo(s, 2):own_hi(s, 2), own_lo(s, 3):own_hi(s, 3), 1) &
                   *y(:, own_lo(s, 2):own_hi(s, 2), own_lo(s, 3):own_hi(s, 3), 1))
      call s%sum_all(red)
      v = red(1)
   end function cell_dot

   !> Fill the halo layers along the decomposed axis from the periodic neighbours.
   subroutine halo(s, x)
      type(stokes_hypre_t), intent(in) :: s
      real(dp), intent(inout) :: x(s%lb(1):, s%lb(2):, s%lb(3):, :)
      integer :: up, down, m
      integer(ip) :: lo, hi
      real(dp), allocatable :: sl(:), su(:), rl(:), ru(:)
      lo = own_lo(s, s%ax)
      hi = own_hi(s, s%ax)
      up = modulo(s%rank + 1, s%nranks)
      down = modulo(s%rank - 1, s%nranks)
      if (s%ax == 2) then
         m = size(x(:, lo, :, :))
         sl = reshape(x(:, lo, :, :), [m])
         su = reshape(x(:, hi, :, :), [m])
      else
         m = size(x(:, :, lo, :))
         sl = reshape(x(:, :, lo, :), [m])
         su = reshape(x(:, :, hi, :), [m])
      end if
      allocate (rl(m), ru(m))
      if (s%nranks == 1) then
         rl = su
         ru = sl
      else
         call MPI_Sendrecv(su, m, MPI_DOUBLE_PRECISION, up, 11, rl, m, MPI_DOUBLE_PRECISION, down, 11, s%comm, &
                           MPI_STATUS_IGNORE)
         call MPI_Sendrecv(sl, m, MPI_DOUBLE_PRECISION, down, 12, ru, m, MPI_DOUBLE_PRECISION, up, 12, s%comm, &
                           MPI_STATUS_IGNORE)
      end if
      if (s%ax == 2) then
         x(:, lo - 1, :, :) = reshape(rl, shape(x(:, lo - 1, :, :)))
         x(:, hi + 1, :, :) = reshape(ru, shape(x(:, hi + 1, :, :)))
      else
         x(:, :, lo - 1, :) = reshape(rl, shape(x(:, :, lo - 1, :)))
         x(:, :, hi + 1, :) = reshape(ru, shape(x(:, :, hi + 1, :)))
      end if
   end subroutine halo

end module fold_stokes_hypre
