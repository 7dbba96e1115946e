!> The hydrodynamics component of a run, chosen once from
!> /setup/resolved/hydrodynamics (fold_run_file: FOLD_HYDRO_JEFFERY, FOLD_HYDRO_STOKES).
module fold_hydro_select
   use fold_run_file, only: run_setup_t, FOLD_HYDRO_STOKES
   use fold_hydro, only: hydro_model_t
   use fold_hydro_jeffery, only: hydro_jeffery_t
   use fold_hydro_stokes, only: hydro_stokes_t
   implicit none
   private

   public :: hydro_select

contains

   !> An uninitialised component of the kind the run asks for (its init makes it).
   subroutine hydro_select(setup, hydro)
      type(run_setup_t), intent(in) :: setup
      class(hydro_model_t), allocatable, intent(out) :: hydro
      if (setup%hydrodynamics == FOLD_HYDRO_STOKES) then
         allocate (hydro_stokes_t :: hydro)
      else
         allocate (hydro_jeffery_t :: hydro)
      end if
   end subroutine hydro_select

end module fold_hydro_select
