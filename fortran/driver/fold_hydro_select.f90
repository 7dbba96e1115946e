!> The hydrodynamics component of a run, chosen once from
!> /setup/resolved/hydrodynamics (fold_run_file: FOLD_HYDRO_JEFFERY, FOLD_HYDRO_STOKES)
!> and made for the run by its implementation's init.
module fold_hydro_select
   use fold_kinds, only: msg_len
   use fold_particles, only: particle_set_t
   use fold_cell, only: cell_t
   use fold_run_file, only: run_setup_t, FOLD_HYDRO_STOKES
   use fold_hydro, only: hydro_model_t
   use fold_hydro_jeffery, only: hydro_jeffery_t, jeffery_init
   use fold_hydro_stokes, only: hydro_stokes_t, stokes_init
   implicit none
   private

   public :: hydro_select

contains

   !> The component of the kind the run asks for, made for the run (rank 0 says what
   !> it is on stdout). On failure `hydro` is allocated but not usable.
   subroutine hydro_select(setup, cell, parts, rank, nranks, hydro, stat, errmsg)
      type(run_setup_t), intent(in) :: setup
      !> The run's cell (its velocity gradient)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      !> This process's rank and the number of ranks of MPI_COMM_WORLD
      integer, intent(in) :: rank, nranks
      class(hydro_model_t), allocatable, intent(out) :: hydro
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(hydro_stokes_t), allocatable :: stokes
      type(hydro_jeffery_t), allocatable :: jeffery

      if (setup%hydrodynamics == FOLD_HYDRO_STOKES) then
         allocate (stokes)
         call stokes_init(stokes, setup, parts, rank, nranks, stat, errmsg)
         call move_alloc(stokes, hydro)
      else
         allocate (jeffery)
         call jeffery_init(jeffery, setup, cell, parts, rank, nranks, stat, errmsg)
         call move_alloc(jeffery, hydro)
      end if
   end subroutine hydro_select

end module fold_hydro_select
