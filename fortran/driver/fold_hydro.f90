!> Hydrodynamics of a run as one component the time loop calls (fold_driver): the
!> velocities of the particles over a step, the flow of a new configuration (its
!> solve and what goes into the record), and the state carried from step to step
!> (fold_time_scheme), which the loop saves for the rollback to the last good state
!> and writes into the checkpoints.
!>
!> Implementations: fold_hydro_jeffery (the exact Jeffery kinematics of the imposed
!> flow) and fold_hydro_stokes (the fictitious-domain Stokes solve, with or without
!> the sphere lubrication correction); fold_hydro_select chooses the one a run's
!> /setup/resolved/hydrodynamics names and makes it with that implementation's own
!> init, which takes what its model needs. The no-flow behaviour is the default of
!> every binding but velocities.
module fold_hydro
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK
   use fold_particles, only: particle_set_t
   use fold_cell, only: cell_t
   use fold_run_file, only: run_setup_t
   use fold_output, only: run_record_t
   use fold_time_scheme, only: time_scheme_state_t
   implicit none
   private

   !> Hydrodynamics of a run.
   type, abstract, public :: hydro_model_t
      !> The records hold the Stokes series (solver, stress; lubrication when on)
      logical :: solves_flow = .false.
      !> Velocity history of the time scheme (empty without a solver: no AB2 history
      !> then, and the checkpoints carry none)
      type(time_scheme_state_t) :: scheme
      !> CG iterations of the solves made so far
      integer(i8) :: cg_iterations = 0
      !> Relative residual of the last solve [-] (NaN: none)
      real(dp) :: residual = 0.0_dp
   contains
      !> v, omega of every particle for the step from t
      procedure(hydro_velocities_i), deferred :: velocities
      !> Carry the stored velocities across the Lees-Edwards wrap just made (default:
      !> nothing stored to carry)
      procedure :: carry_across_wrap => no_carry
      !> A solve of the configuration is due after `step` (default: never)
      procedure :: solve_due => never_due
      !> Flow of the current configuration: the velocities of the next step and the
      !> stress of its record (default: no flow to solve)
      procedure :: solve_configuration => no_solve
      !> Release what init made (default: nothing)
      procedure :: destroy => no_destroy
   end type hydro_model_t

   abstract interface
      subroutine hydro_velocities_i(self, cell, parts, t, first, last)
         import :: hydro_model_t, cell_t, particle_set_t, dp, ip
         class(hydro_model_t), intent(inout) :: self
         !> The cell at time t
         type(cell_t), intent(in) :: cell
         type(particle_set_t), intent(inout) :: parts
         !> Start of the step [s]
         real(dp), intent(in) :: t
         !> This rank's block of particles
         integer(ip), intent(in) :: first, last
      end subroutine hydro_velocities_i
   end interface

contains

   !> No velocities stored: nothing to carry across the wrap.
   subroutine no_carry(self, cell, x_before)
      class(hydro_model_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      !> Positions before the wrap (dim, n) [m]
      real(dp), intent(in) :: x_before(:, :)
   end subroutine no_carry

   !> No solve is ever due.
   logical function never_due(self, step)
      class(hydro_model_t), intent(in) :: self
      integer(i8), intent(in) :: step
      never_due = .false.
   end function never_due

   !> No flow to solve: rec and the particles are left as they are.
   subroutine no_solve(self, cell, parts, t, rec, stat, errmsg, untrusted)
      class(hydro_model_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      !> The configuration (its v, omega are left as they are)
      type(particle_set_t), intent(inout) :: parts
      !> Time of the configuration [s]
      real(dp), intent(in) :: t
      !> Record the solve's statistics and stress go into
      type(run_record_t), intent(inout) :: rec
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> The solve failed the stress check: no number of it went into rec
      logical, intent(out) :: untrusted
      stat = FOLD_OK
      errmsg = ""
      untrusted = .false.
   end subroutine no_solve

   !> Nothing to release.
   subroutine no_destroy(self)
      class(hydro_model_t), intent(inout) :: self
   end subroutine no_destroy

end module fold_hydro
