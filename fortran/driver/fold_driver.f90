!> The run driver: reads a run file, advances the particles, appends the results.
!>
!> One step from t to t + dt:
!>   1. hydrodynamics: the velocities (v, omega) of the step from the run's
!>      hydrodynamics component (fold_hydro: the exact Jeffery kinematics,
!>      fold_hydro_jeffery, or the Stokes solve combined in time, fold_hydro_stokes),
!>      chosen once from /setup/resolved/hydrodynamics (fold_hydro_select);
!>   2. contacts: the seed's collision strategy on (v, omega) at the predicted
!>      configuration (`fold_contacts::resolve_contacts`, corrections summed over ranks
!>      after every sweep);
!>   3. exact rigid update (`fold_kinematics::rigid_update`), positions wrapped into
!>      the Lees-Edwards cell at t + dt, the component's stored velocities with them;
!>   4. blow-up checks (a particle moving more than half the cell in one step;
!>      NaN/infinity anywhere in x, p, v, omega), drift measures;
!>   5. the flow of the new configuration when the component solves one (the stress
!>      of this step's record, the velocities of the next step);
!>   6. statistics (`fold_orientation_stats`) and output every `output_every` steps,
!>      snapshots and checkpoints at their own intervals.
!>
!> MPI: the particle state is replicated on every rank of MPI_COMM_WORLD; rank r owns
!> the contiguous block first:last = r*n/np+1 : (r+1)*n/np for kinematics and contact
!> corrections. Every rank then performs the same rigid update on the same data, so
!> the state stays replicated; results differ from a serial run only by the order of
!> the rank sum of contact corrections (round-off). Rank 0 alone writes the file and
!> broadcasts the status of each write, so an I/O failure stops every rank.
!>
!> Failure (contact cap with on_cap = stop, NaN, Stokes solver not converged:
!> the message gives the residual reached, the iterations and kappa; an untrustworthy
!> stress, an effective viscosity below the fluid's (`fold_stokes_trust`), fails the
!> step whose record would hold it): the state at the start of the
!> failing step (the last good state) is restored and written as the last record,
!> a snapshot and /checkpoint; the root attribute `status` says "failed: step N,
!> t = T: cause" and `steps_done` = N - 1. I/O failure (the first failed HDF5 call
!> while writing the outputs of step N, fail_io): nothing more is written but the
!> status "failed: step N, t = T: I/O: ..." (best effort, in a reopened file: see
!> fold_output::output_failed_status); the whole records, snapshots and the last
!> complete checkpoint stay as they were, `steps_done` = the step of the last whole
!> record. Beside `status`, the outcome attributes (fold_outcome) give the same as
!> data: code, step, time, cause, residual. Nothing here stops the program: the
!> outcome is returned to `fold_run`.
module fold_driver
   use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use mpi_f08
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_IO_ERROR, FOLD_NUMERICAL
   use fold_particles, only: particle_set_t
   use fold_cell, only: cell_t, cell_init, cell_set_time, cell_wrap, cell_wall_speed, cell_deforming
   use fold_kinematics, only: rigid_update
   use fold_contacts, only: contact_config_t, contact_stats_t, resolve_contacts, FOLD_CONTACT_NONE
   use fold_orientation_stats, only: orientation_moments
   use fold_h5, only: h5_start, h5_stop
   use fold_run_file, only: run_setup_t, read_run_file, FOLD_HYDRO_STOKES
   use fold_hydro, only: hydro_model_t
   use fold_hydro_select, only: hydro_select
   use fold_outcome, only: outcome_t, outcome_of_status, OUTCOME_COMPLETED, OUTCOME_IO_ERROR, &
                           OUTCOME_UNTRUSTED_STRESS
   use fold_output, only: run_output_t, run_record_t, record_init, output_open, output_resume, output_record, &
                          output_snapshot, output_checkpoint, output_status, output_close, output_failed_status, &
                          output_abandon
   implicit none
   private

   !> How a run ended.
   type, public :: run_outcome_t
      !> FOLD_OK or the failure status
      integer :: stat = FOLD_OK
      !> Cause of the failure ("" on success)
      character(len=msg_len) :: errmsg = ""
      !> The run file was rejected before any step (fold_run exits with 2)
      logical :: bad_input = .false.
      !> Steps completed (the state in the file is after this step)
      integer(i8) :: steps_done = 0
      !> Time of that state [s]
      real(dp) :: time = 0.0_dp
   end type run_outcome_t

   !> Everything a run carries from step to step.
   type :: run_t
      !> Run file, and whether the run continues from its /checkpoint
      character(len=:), allocatable :: path
      logical :: resume = .false.
      !> This process's rank, the number of ranks, its block of particles
      integer :: rank = 0, nranks = 1
      integer(ip) :: first = 1, last = 0
      type(run_setup_t) :: setup
      !> The particles, and their state at the start of the current step (last good state)
      type(particle_set_t) :: parts, good
      type(cell_t) :: cell
      type(contact_config_t) :: contacts
      type(contact_stats_t) :: contact_stats
      class(hydro_model_t), allocatable :: hydro
      type(run_output_t) :: out
      !> Interval aggregates of the next record
      type(run_record_t) :: rec
      !> First step of this process's loop minus one, time of the state [s]
      integer(i8) :: step0 = 0
      real(dp) :: t = 0.0_dp
      !> Steps of the last record and snapshot made (-1: none)
      integer(i8) :: last_record = -1, last_snapshot = -1
      !> Rank 0: step of the last record / checkpoint completely written (-1: none yet)
      integer(i8) :: whole_record = -1, whole_checkpoint = -1
      !> Cost of the time loop (printed at its end): clock ticks, CPU seconds of this process
      integer(i8) :: tick0 = 0, tick_rate = 1
      real(dp) :: cpu0 = 0.0_dp
   end type run_t

   public :: run_driver, measure_gaps

contains

   !> Run (or resume) the simulation described by a run file, on MPI_COMM_WORLD.
   subroutine run_driver(path, resume, outcome)
      !> Run file (/setup/resolved and /initial present; results are appended)
      character(len=*), intent(in) :: path
      !> Continue from /checkpoint instead of starting from /initial
      logical, intent(in) :: resume
      type(run_outcome_t), intent(out) :: outcome
      type(run_t) :: run
      integer :: stat
      character(len=msg_len) :: errmsg
      integer(i8) :: step
      logical :: bad_input, ended

      run%path = path
      run%resume = resume
      bad_input = .false.
      call MPI_Comm_rank(MPI_COMM_WORLD, run%rank)
      call MPI_Comm_size(MPI_COMM_WORLD, run%nranks)
      call h5_start(stat, errmsg)
      if (stat == FOLD_OK) call prepare_run(run, stat, errmsg, bad_input)
      if (stat == FOLD_OK) then
         call open_results(run, stat, errmsg)
         bad_input = stat == FOLD_INPUT_ERROR
      end if
      if (stat /= FOLD_OK) then
         ! before any step: rejected run file or unusable output file
         outcome%stat = stat
         outcome%errmsg = errmsg
         outcome%bad_input = bad_input
         call h5_stop()
         return
      end if

      call start_run(run, outcome, ended)
      if (ended) return
      call system_clock(run%tick0, run%tick_rate)
      call cpu_time(run%cpu0)
      run%good = run%parts
      do step = run%step0 + 1, run%setup%nsteps
         call advance(run, step, outcome, ended)
         if (ended) return
      end do
      call finish_run(run, outcome)
   end subroutine run_driver

   !> Read the run file, make the cell, the contact settings and the hydrodynamics
   !> component; `bad_input`: a failure is the run file's (exit 2).
   subroutine prepare_run(run, stat, errmsg, bad_input)
      type(run_t), intent(inout) :: run
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      logical, intent(out) :: bad_input

      bad_input = .true.
      call read_run_file(run%path, run%setup, run%parts, stat, errmsg)
      if (stat == FOLD_OK) call make_cell(run%setup, run%cell, stat, errmsg)
      if (stat /= FOLD_OK) return
      run%contacts = contact_config_t(mode=run%setup%collisions, alpha=run%setup%alpha, &
                                      max_iter=run%setup%contact_max_iter, on_cap=run%setup%on_contact_cap, &
                                      lubrication=run%setup%lubrication)
      ! A measuring pass now turns a cell too small for the contact search into a
      ! run-file error instead of a failure at step 1.
      call measure_gaps(run%cell, run%parts, run%contacts, run%contact_stats, stat, errmsg)
      if (stat /= FOLD_OK) return
      call hydro_select(run%setup, run%cell, run%parts, run%rank, run%nranks, run%hydro, stat, errmsg)
      bad_input = stat == FOLD_INPUT_ERROR
      if (stat /= FOLD_OK) return
      run%first = int(int(run%rank, i8)*run%parts%n/run%nranks + 1, ip)
      run%last = int(int(run%rank + 1, i8)*run%parts%n/run%nranks, ip)
   end subroutine prepare_run

   !> Rank 0 opens the run file for the results (new, or at its checkpoint on resume);
   !> every rank learns the status.
   subroutine open_results(run, stat, errmsg)
      type(run_t), intent(inout) :: run
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: close_stat
      character(len=msg_len) :: close_msg

      associate (s => run%setup, scheme => run%hydro%scheme)
         call record_init(run%rec, run%parts%dim, s%n_families)
         ! Every rank has closed the run file: rank 0 may now open it for writing
         ! (HDF5 file locks refuse a writer while readers hold the file).
         call MPI_Barrier(MPI_COMM_WORLD)
         stat = FOLD_OK
         errmsg = ""
         if (run%rank == 0) then
            if (run%resume) then
               call output_resume(run%out, run%path, run%parts, s%n_families, run%nranks, run%step0, run%t, &
                                  stat, errmsg, run%hydro%solves_flow, scheme%history%v, scheme%history%omega, &
                                  scheme%history%held, lubrication=s%lubrication)
            else
               call output_open(run%out, run%path, run%parts, s%n_families, run%nranks, stat, errmsg, &
                                run%hydro%solves_flow, s%lubrication)
            end if
         end if
      end associate
      call share_status(stat, errmsg)
      if (stat == FOLD_OK) return
      if (run%rank == 0) then
         if (stat == FOLD_IO_ERROR) then
            call output_abandon(run%out, close_stat, close_msg)  ! a write failed: close without writing more
         else
            call output_close(run%out, close_stat, close_msg)
         end if
      end if
      if (stat == FOLD_IO_ERROR) errmsg = "I/O: preparing the results in "//run%path//" failed: "//trim(errmsg)
   end subroutine open_results

   !> The state the loop starts from (the checkpoint's on resume, shared by every rank),
   !> the flow of that configuration and, for a new run, the outputs of step 0.
   !> `ended`: the run failed (outcome set).
   subroutine start_run(run, outcome, ended)
      type(run_t), intent(inout) :: run
      type(run_outcome_t), intent(inout) :: outcome
      logical, intent(out) :: ended
      integer :: stat
      character(len=msg_len) :: errmsg
      logical :: untrusted

      ended = .false.
      if (run%resume) then
         run%whole_checkpoint = run%step0
         call MPI_Bcast(run%step0, 1, MPI_INTEGER8, 0, MPI_COMM_WORLD)
         call MPI_Bcast(run%t, 1, MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(run%parts%x, size(run%parts%x), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(run%parts%p, size(run%parts%p), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(run%parts%v, size(run%parts%v), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(run%parts%omega, size(run%parts%omega), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         associate (history => run%hydro%scheme%history)
            call MPI_Bcast(history%held, 1, MPI_LOGICAL, 0, MPI_COMM_WORLD)
            call MPI_Bcast(history%v, size(history%v), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
            call MPI_Bcast(history%omega, size(history%omega), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         end associate
         ! positions at the checkpoint time (not the initial ones) decide the first gaps
         call measure_gaps(run%cell, run%parts, run%contacts, run%contact_stats, stat, errmsg)
         run%last_record = run%step0
         run%last_snapshot = run%step0
      end if
      call reset_record(run%rec)
      call accumulate(run%rec, run%contact_stats, run%parts)
      call keep_good(run, .true.)
      ! flow of the starting configuration: velocities of the first step, stress of its record
      call cell_set_time(run%cell, run%t)
      call run%hydro%solve_configuration(run%cell, run%parts, run%t, run%rec, stat, errmsg, untrusted)
      if (stat /= FOLD_OK) then
         if (untrusted) then
            ! the starting configuration has no trusted stress: its record reads NaN
            run%rec%stress = ieee_value(1.0_dp, ieee_quiet_nan)
            run%rec%effective_viscosity = ieee_value(1.0_dp, ieee_quiet_nan)
         end if
         call fail(run, run%step0 + 1, trim(errmsg), stat, outcome, untrusted)
         ended = .true.
         return
      end if
      if (.not. run%resume) then
         call write_outputs(run, 0_i8, 0.0_dp, .true., stat, errmsg)
         if (stat /= FOLD_OK) then
            call fail_io(run, 0_i8, errmsg, outcome)
            ended = .true.
            return
         end if
      end if
      run%last_record = run%step0
      run%last_snapshot = run%step0
      call reset_record(run%rec)
   end subroutine start_run

   !> One step, from t = (step - 1) dt to step dt (see the module header); `ended`: the
   !> run failed at it (outcome set).
   subroutine advance(run, step, outcome, ended)
      type(run_t), intent(inout) :: run
      integer(i8), intent(in) :: step
      type(run_outcome_t), intent(inout) :: outcome
      logical, intent(out) :: ended
      integer :: stat
      character(len=msg_len) :: errmsg
      character(len=200) :: why
      real(dp), allocatable :: x_before(:, :)
      integer(ip) :: k
      logical :: untrusted

      ended = .true.
      associate (s => run%setup, parts => run%parts, cell => run%cell)
         call keep_good(run, .false.)
         run%t = real(step - 1, dp)*s%dt
         call cell_set_time(cell, run%t)
         call run%hydro%velocities(cell, parts, run%t, run%first, run%last)
         if (run%nranks > 1) then
            call resolve_contacts(cell, parts, s%dt, run%contacts, run%contact_stats, stat, errmsg, run%first, &
                                  run%last, reduce_world)
         else
            call resolve_contacts(cell, parts, s%dt, run%contacts, run%contact_stats, stat, errmsg)
         end if
         if (stat /= FOLD_OK) then
            call fail(run, step, trim(errmsg), stat, outcome)
            return
         end if
         if (step_too_long(parts, s%dt, s%cell_lengths, why)) then
            call fail(run, step, trim(why), FOLD_NUMERICAL, outcome)
            return
         end if
         call rigid_update(parts, s%dt)
         run%t = real(step, dp)*s%dt
         call cell_set_time(cell, run%t)
         x_before = parts%x
         do k = 1, parts%n
            call cell_wrap(cell, parts%x(:, k), parts%v(:, k))
         end do
         call run%hydro%carry_across_wrap(cell, x_before)
         if (.not. finite_state(parts)) then
            call fail(run, step, "NaN or infinity in the particle state (x, p, v or omega); dt too large?", &
                      FOLD_NUMERICAL, outcome)
            return
         end if
         call accumulate(run%rec, run%contact_stats, parts)
         if (run%hydro%solve_due(step)) then
            ! flow of the new configuration: the stress of this record, the velocities of the next step
            call run%hydro%solve_configuration(cell, parts, run%t, run%rec, stat, errmsg, untrusted)
            if (stat /= FOLD_OK .and. untrusted) then
               ! the stress of this step's record is not a result: the step fails, the
               ! state before it (good, its record already trusted) is kept
               call fail(run, step, trim(errmsg), stat, outcome, untrusted)
               return
            end if
            if (stat /= FOLD_OK) then
               ! the configuration at t is good; it is the next step that cannot be made
               call keep_good(run, .false.)
               call fail(run, step + 1, trim(errmsg), stat, outcome)
               return
            end if
         end if
         call write_outputs(run, step, run%t, step == s%nsteps, stat, errmsg)
         if (stat /= FOLD_OK) then
            call fail_io(run, step, errmsg, outcome)
            return
         end if
         if (run%rank == 0 .and. (mod(step, max(1_i8, s%nsteps/100)) == 0 .or. step == s%nsteps)) then
            write (output_unit, '(a,1x,i0,1x,i0,1x,es23.16)') "PROGRESS", step, s%nsteps, run%t
            flush (output_unit)
         end if
      end associate
      ended = .false.
   end subroutine advance

   !> A particle crossing more than half the cell in one step makes the minimum image
   !> (and so every gap) meaningless: a blow-up, not a result (`why` says which).
   logical function step_too_long(parts, dt, cell_lengths, why)
      type(particle_set_t), intent(in) :: parts
      real(dp), intent(in) :: dt, cell_lengths(:)
      character(len=*), intent(out) :: why
      real(dp) :: jump
      integer(ip) :: kmax

      jump = 0.0_dp
      kmax = 0
      why = ""
      if (parts%n > 0) then
         kmax = int(maxloc(norm2(parts%v, dim=1), dim=1), ip)
         jump = norm2(parts%v(:, kmax))*dt
      end if
      step_too_long = .not. (jump <= 0.5_dp*minval(cell_lengths(1:parts%dim)))
      if (step_too_long) write (why, '(a,i0,a,es10.3,a)') "particle ", kmax - 1, " would move ", jump, &
         " in one step, more than half the cell; dt too large"
   end function step_too_long

   !> The current state is the last good one (the rollback of a failing step returns
   !> to it); `whole`: copy the particle set entirely (else its x, p, v, omega).
   subroutine keep_good(run, whole)
      type(run_t), intent(inout) :: run
      logical, intent(in) :: whole
      if (whole) then
         run%good = run%parts
      else
         run%good%x = run%parts%x
         run%good%p = run%parts%p
         run%good%v = run%parts%v
         run%good%omega = run%parts%omega
      end if
      call run%hydro%scheme%keep_good()
   end subroutine keep_good

   !> After the last step: the cost line, status "ok" and the outcome, close.
   subroutine finish_run(run, outcome)
      type(run_t), intent(inout) :: run
      type(run_outcome_t), intent(inout) :: outcome
      type(outcome_t) :: done
      integer(i8) :: tick1
      real(dp) :: cpu1
      integer :: stat, close_stat
      character(len=msg_len) :: errmsg, close_msg

      call cpu_time(cpu1)
      call system_clock(tick1)
      stat = FOLD_OK
      errmsg = ""
      if (run%rank == 0) then
         ! benchmarks/bench_stokes_step.py reads this line
         write (output_unit, '(a,i0,a,es12.5,a,es12.5,a,i0)') "TIMING steps=", run%setup%nsteps - run%step0, &
            " wall=", real(tick1 - run%tick0, dp)/real(max(run%tick_rate, 1_i8), dp), " cpu=", cpu1 - run%cpu0, &
            " cg_iterations=", run%hydro%cg_iterations
         flush (output_unit)
         done = outcome_t(code=OUTCOME_COMPLETED, step=run%setup%nsteps, time=run%t, cause="", &
                          residual=run%hydro%residual)
         call output_status(run%out, "ok", run%setup%nsteps, stat, errmsg, done)
         if (stat == FOLD_OK) then
            call output_close(run%out, stat, errmsg)
         else
            ! a failed flush: close without writing more (status stays "running")
            call output_abandon(run%out, close_stat, close_msg)
         end if
      end if
      call share_status(stat, errmsg)
      call run%hydro%destroy()
      outcome%stat = stat
      outcome%steps_done = run%setup%nsteps
      outcome%time = run%t
      if (stat /= FOLD_OK) then
         ! every step is computed and written; only the final status or the close failed
         write (close_msg, '(a,i0,a)') "I/O: recording the end of the run (step ", run%setup%nsteps, ") failed: "
         outcome%errmsg = trim(close_msg)//" "//trim(errmsg)// &
                          "; the records and the checkpoint are whole, but the status attribute may still read 'running'"
      end if
      call h5_stop()
   end subroutine finish_run

   !> Record / snapshot / checkpoint due at step `st` (rank 0 writes; all ranks learn
   !> the status).
   subroutine write_outputs(run, st, time, final, stat, errmsg)
      type(run_t), intent(inout) :: run
      integer(i8), intent(in) :: st
      real(dp), intent(in) :: time
      logical, intent(in) :: final
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      stat = FOLD_OK
      errmsg = ""
      associate (s => run%setup)
         if (run%rank == 0) then
            if (mod(st, s%output_every) == 0 .or. final) then
               call fill_record(run%rec, st, time, run%parts, s%n_families)
               call output_record(run%out, run%rec, stat, errmsg)
               if (stat == FOLD_OK) then
                  call reset_record(run%rec)
                  run%whole_record = st
               end if
            end if
            if (stat == FOLD_OK .and. s%snapshot_every > 0) then
               if (mod(st, s%snapshot_every) == 0 .or. final) &
                  call output_snapshot(run%out, st, time, run%parts, stat, errmsg)
            end if
            if (stat == FOLD_OK .and. s%checkpoint_every > 0) then
               if (mod(st, s%checkpoint_every) == 0 .or. final) then
                  call checkpoint(run, st, time, stat, errmsg)
                  if (stat == FOLD_OK) run%whole_checkpoint = st
               end if
            end if
         end if
         if (mod(st, s%output_every) == 0 .or. final) then
            run%last_record = st
            call reset_record(run%rec)
         end if
         if (s%snapshot_every > 0) then
            if (mod(st, s%snapshot_every) == 0 .or. final) run%last_snapshot = st
         end if
      end associate
      call share_status(stat, errmsg)
   end subroutine write_outputs

   !> Write /checkpoint (with the time scheme's history when it holds one).
   subroutine checkpoint(run, st, time, stat, errmsg)
      type(run_t), intent(inout) :: run
      integer(i8), intent(in) :: st
      real(dp), intent(in) :: time
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      associate (history => run%hydro%scheme%history)
         if (history%held) then
            call output_checkpoint(run%out, st, time, run%parts, stat, errmsg, history%v, history%omega)
         else
            call output_checkpoint(run%out, st, time, run%parts, stat, errmsg)
         end if
      end associate
   end subroutine checkpoint

   !> Stop at `failed_step` (its status `code`; `untrusted`: a solve's stress failed its
   !> check): restore the last good state, write it, set status and outcome.
   subroutine fail(run, failed_step, cause, code, outcome, untrusted)
      type(run_t), intent(inout) :: run
      integer(i8), intent(in) :: failed_step
      character(len=*), intent(in) :: cause
      integer, intent(in) :: code
      type(run_outcome_t), intent(inout) :: outcome
      logical, intent(in), optional :: untrusted
      integer(i8) :: good_step
      real(dp) :: good_t
      type(outcome_t) :: ending
      character(len=msg_len) :: text, write_msg
      integer :: write_stat

      good_step = failed_step - 1
      good_t = real(good_step, dp)*run%setup%dt
      if (good_step >= 0 .and. allocated(run%good%x)) then
         run%parts%x = run%good%x
         run%parts%p = run%good%p
         run%parts%v = run%good%v
         run%parts%omega = run%good%omega
         call run%hydro%scheme%restore_good()
      end if
      write (text, '(a,i0,a,es23.16,a,a)') "failed: step ", failed_step, ", t = ", &
         real(failed_step, dp)*run%setup%dt, ": ", trim(cause)
      ending = outcome_t(code=outcome_of_status(code), step=failed_step, time=real(failed_step, dp)*run%setup%dt, &
                        cause=cause, residual=run%hydro%residual)
      if (present(untrusted)) then
         if (untrusted) ending%code = OUTCOME_UNTRUSTED_STRESS
      end if
      write_stat = FOLD_OK
      write_msg = ""
      if (run%rank == 0 .and. run%out%file >= 0) then
         ! Each write only after the previous one succeeded: a file that refuses one
         ! (full disk) is not written into further, apart from the status (best effort).
         if (run%last_record /= good_step .and. good_step >= 0) then
            call fill_record(run%rec, good_step, good_t, run%parts, run%setup%n_families)
            call output_record(run%out, run%rec, write_stat, write_msg)
         end if
         if (write_stat == FOLD_OK .and. run%last_snapshot /= good_step .and. good_step >= 0) &
            call output_snapshot(run%out, good_step, good_t, run%parts, write_stat, write_msg)
         if (write_stat == FOLD_OK .and. good_step >= 0) call checkpoint(run, good_step, good_t, write_stat, write_msg)
         if (write_stat /= FOLD_OK) text = trim(text)//"; writing the last good state failed too: I/O: "// &
                                           trim(write_msg)
         call record_status(run, text, max(good_step, 0_i8), write_stat == FOLD_OK, ending)
      end if
      outcome%stat = code
      outcome%errmsg = text
      outcome%steps_done = max(good_step, 0_i8)
      outcome%time = good_t
      call run%hydro%destroy()
      call h5_stop()
   end subroutine fail

   !> Stop after the outputs of step `st` could not be written (`cause`: the first
   !> failed HDF5 call, naming the dataset). Nothing more is written into the file but
   !> the status (best effort: on a full disk that may fail too, and stderr says so):
   !> the whole records and snapshots (records_complete, snapshots_complete) and the
   !> last complete checkpoint stay as they are, so readers and --resume see the
   !> last good state. steps_done = the step of the last whole record.
   subroutine fail_io(run, st, cause, outcome)
      type(run_t), intent(inout) :: run
      integer(i8), intent(in) :: st
      character(len=*), intent(in) :: cause
      type(run_outcome_t), intent(inout) :: outcome
      character(len=msg_len) :: text, kept_text, io_cause
      integer(i8) :: kept

      write (io_cause, '(a,i0,a,a)') "I/O: writing the outputs of step ", st, " failed: ", trim(cause)
      write (text, '(a,i0,a,es23.16,a,a)') "failed: step ", st, ", t = ", real(st, dp)*run%setup%dt, ": ", &
         trim(io_cause)
      kept = max(run%whole_record, 0_i8)
      if (run%rank == 0) then
         if (run%whole_record >= 0) then
            write (kept_text, '(a,i0)') "; the file keeps the whole records up to step ", run%whole_record
         else if (run%resume) then
            kept_text = "; the file keeps the whole records written before this resume"
            kept = run%step0
         else
            kept_text = "; no record of this run is complete in the file"
         end if
         if (run%whole_checkpoint >= 0) write (kept_text, '(a,a,i0,a)') trim(kept_text), &
            " and the checkpoint of step ", run%whole_checkpoint, " (continue with --resume once there is space)"
         text = trim(text)//trim(kept_text)
         io_cause = trim(io_cause)//trim(kept_text)
         if (run%out%file >= 0) call record_status(run, text, kept, .false., &
                                                   outcome_t(code=OUTCOME_IO_ERROR, step=st, &
                                                             time=real(st, dp)*run%setup%dt, cause=io_cause, &
                                                             residual=run%hydro%residual))
      end if
      call MPI_Bcast(text, msg_len, MPI_CHARACTER, 0, MPI_COMM_WORLD)
      outcome%stat = FOLD_IO_ERROR
      outcome%errmsg = text
      call MPI_Bcast(kept, 1, MPI_INTEGER8, 0, MPI_COMM_WORLD)
      outcome%steps_done = kept
      outcome%time = real(outcome%steps_done, dp)*run%setup%dt
      call run%hydro%destroy()
      call h5_stop()
   end subroutine fail_io

   !> Rank 0: set `status`, `steps_done` and the outcome, flush and close the file;
   !> stderr says so when that failed (the status then reads "running", or is missing).
   subroutine record_status(run, text, done, clean, ending)
      type(run_t), intent(inout) :: run
      character(len=*), intent(in) :: text
      integer(i8), intent(in) :: done
      !> Every write so far succeeded (else the file is closed without writing more
      !> into it and reopened for the status: output_failed_status)
      logical, intent(in) :: clean
      type(outcome_t), intent(in) :: ending
      integer :: ss, sc
      character(len=msg_len) :: ms, mc
      if (clean) then
         call output_status(run%out, trim(text), done, ss, ms, ending)
         if (ss == FOLD_OK) then
            call output_close(run%out, ss, ms)
         else
            call output_abandon(run%out, sc, mc)  ! the flush failed: close without writing more
            if (sc /= FOLD_OK) ms = trim(ms)//"; "//trim(mc)
         end if
      else
         call output_failed_status(run%out, run%path, trim(text), done, ss, ms, ending)
      end if
      if (ss /= FOLD_OK) then
         write (error_unit, '(a)') "fold_run: the failure could not be recorded in "//run%path// &
            " (status attribute: I/O: "//trim(ms)//"); its status attribute may still read 'running'"
         flush (error_unit)
      end if
   end subroutine record_status

   !> Surface gaps of a configuration as it is (zero velocities over a vanishing
   !> step), through the same contact pass as the run, without corrections.
   subroutine measure_gaps(cell, parts, cfg, cstats, stat, errmsg)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      type(contact_config_t), intent(in) :: cfg
      type(contact_stats_t), intent(out) :: cstats
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(particle_set_t) :: still
      type(contact_config_t) :: measuring

      still = parts
      still%v = 0.0_dp
      still%omega = 0.0_dp
      measuring = cfg
      measuring%mode = FOLD_CONTACT_NONE
      call resolve_contacts(cell, still, tiny(1.0_dp), measuring, cstats, stat, errmsg)
   end subroutine measure_gaps

   !> Sum over ranks of the contact corrections and counters, minimum of the gaps
   !> (the reduction `fold_contacts` calls after each sweep).
   subroutine reduce_world(dv, domega, counts, mins)
      real(dp), intent(inout) :: dv(:, :), domega(:, :)
      integer(i8), intent(inout) :: counts(:)
      real(dp), intent(inout) :: mins(:)
      call MPI_Allreduce(MPI_IN_PLACE, dv, size(dv), MPI_DOUBLE_PRECISION, MPI_SUM, MPI_COMM_WORLD)
      call MPI_Allreduce(MPI_IN_PLACE, domega, size(domega), MPI_DOUBLE_PRECISION, MPI_SUM, MPI_COMM_WORLD)
      call MPI_Allreduce(MPI_IN_PLACE, counts, size(counts), MPI_INTEGER8, MPI_SUM, MPI_COMM_WORLD)
      call MPI_Allreduce(MPI_IN_PLACE, mins, size(mins), MPI_DOUBLE_PRECISION, MPI_MIN, MPI_COMM_WORLD)
   end subroutine reduce_world

   !> Rank 0's status and message to every rank.
   subroutine share_status(stat, errmsg)
      integer, intent(inout) :: stat
      character(len=msg_len), intent(inout) :: errmsg
      call MPI_Bcast(stat, 1, MPI_INTEGER, 0, MPI_COMM_WORLD)
      call MPI_Bcast(errmsg, msg_len, MPI_CHARACTER, 0, MPI_COMM_WORLD)
   end subroutine share_status

   !> The cell of the run, checking the redundant entries of /setup/resolved against G.
   subroutine make_cell(setup, cell, stat, errmsg)
      type(run_setup_t), intent(in) :: setup
      type(cell_t), intent(out) :: cell
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp) :: gd, u
      real(dp), parameter :: rel = 1.0e-9_dp

      call cell_init(cell, setup%dim, setup%cell_lengths, setup%walls, setup%velocity_gradient, stat, errmsg)
      if (stat /= FOLD_OK) then
         errmsg = "/setup/resolved/velocity_gradient or cell_lengths: "//trim(errmsg)
         return
      end if
      ! shear_rate is the scalar deformation rate sqrt(2 D:D) (|G_xy| in simple shear)
      gd = sqrt(0.5_dp*sum((setup%velocity_gradient(1:setup%dim, 1:setup%dim) + &
                            transpose(setup%velocity_gradient(1:setup%dim, 1:setup%dim)))**2))
      if (abs(abs(setup%shear_rate) - gd) > rel*max(gd, tiny(1.0_dp))) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,es12.5,a,es12.5,a)') "/setup/resolved/shear_rate = ", setup%shear_rate, &
            " disagrees with sqrt(2 D:D) of velocity_gradient = ", gd, " (must be equal)"
         return
      end if
      if (setup%hydrodynamics == FOLD_HYDRO_STOKES .and. cell_deforming(cell)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "/setup/resolved/hydrodynamics = 1 (stokes) needs a simple shear velocity_gradient: the FFT "// &
                  "Stokes solver has no deforming (elongational) lattice yet"
         return
      end if
      if (setup%walls) then
         u = cell_wall_speed(cell)
         if (abs(setup%wall_speed - u) > rel*max(abs(u), tiny(1.0_dp))) then
            stat = FOLD_INPUT_ERROR
            write (errmsg, '(a,es12.5,a,es12.5,a)') "/setup/resolved/wall_speed = ", setup%wall_speed, &
               " disagrees with shear_rate*Ly/2 = ", u, " (walls move at -U and +U)"
            return
         end if
      end if
   end subroutine make_cell

   !> All of x, p, v, omega finite.
   logical function finite_state(parts)
      type(particle_set_t), intent(in) :: parts
      real(dp), parameter :: big = huge(1.0_dp)
      finite_state = all(abs(parts%x) <= big) .and. all(abs(parts%p) <= big) .and. &
                     all(abs(parts%v) <= big) .and. all(abs(parts%omega) <= big)
   end function finite_state

   !> Empty the interval aggregates of a record.
   subroutine reset_record(rec)
      type(run_record_t), intent(inout) :: rec
      rec%n_corrections = 0
      rec%contact_iterations = 0
      rec%pairs_left = 0
      rec%capped_steps = 0
      rec%min_gap = huge(1.0_dp)
      rec%min_gap_over_alpha = huge(1.0_dp)
      rec%length_drift = 0.0_dp
      rec%unit_norm_drift = 0.0_dp
      rec%stokes_iterations = 0
      rec%stokes_residual = 0.0_dp
      rec%rigidity_max = 0.0_dp
      rec%rigidity_mean = 0.0_dp
      rec%lubricated_pairs = 0
      rec%lubrication_correction = 0.0_dp
   end subroutine reset_record

   !> Fold one step's contact statistics and drifts into the interval aggregates.
   subroutine accumulate(rec, cstats, parts)
      type(run_record_t), intent(inout) :: rec
      type(contact_stats_t), intent(in) :: cstats
      type(particle_set_t), intent(in) :: parts
      integer(ip) :: k
      real(dp) :: pn, ends

      rec%n_corrections = rec%n_corrections + cstats%n_corrections
      rec%contact_iterations = max(rec%contact_iterations, int(cstats%iterations, i8))
      rec%pairs_left = max(rec%pairs_left, cstats%pairs_left)
      if (cstats%capped) rec%capped_steps = rec%capped_steps + 1
      rec%min_gap = min(rec%min_gap, cstats%min_gap)
      rec%min_gap_over_alpha = min(rec%min_gap_over_alpha, cstats%min_gap_over_alpha)
      do k = 1, parts%n
         pn = norm2(parts%p(:, k))
         rec%unit_norm_drift = max(rec%unit_norm_drift, abs(pn - 1.0_dp))
         ! end points X1,2 = x -+ (L/2) p as the seed's end-point scheme would hold them
         ends = norm2((parts%x(:, k) + 0.5_dp*parts%length(k)*parts%p(:, k)) - &
                      (parts%x(:, k) - 0.5_dp*parts%length(k)*parts%p(:, k)))
         rec%length_drift = max(rec%length_drift, abs(ends - parts%length(k))/parts%length(k))
      end do
   end subroutine accumulate

   !> Orientation tensors of the whole set and of each family (number averages).
   subroutine fill_record(rec, step, time, parts, nfam)
      type(run_record_t), intent(inout) :: rec
      integer(i8), intent(in) :: step
      real(dp), intent(in) :: time
      type(particle_set_t), intent(in) :: parts
      integer(ip), intent(in) :: nfam
      real(dp), allocatable :: pf(:, :)
      integer(ip) :: f, m
      integer :: stat
      character(len=msg_len) :: errmsg

      rec%step = step
      rec%time = time
      ! NaN cannot reach here (finite_state is checked first); stat only reports that.
      call orientation_moments(parts%dim, parts%n, parts%p, spread(1.0_dp, 1, parts%n), rec%a2, rec%a4, stat, errmsg)
      do f = 0, nfam - 1
         m = count(parts%family == f)
         rec%a2_family(:, :, f + 1) = 0.0_dp
         rec%a4_family(:, :, :, :, f + 1) = 0.0_dp
         if (m == 0) cycle
         pf = reshape(pack(parts%p, spread(parts%family == f, 1, parts%dim)), [parts%dim, m])
         call orientation_moments(parts%dim, m, pf, spread(1.0_dp, 1, m), rec%a2_family(:, :, f + 1), &
                                  rec%a4_family(:, :, :, :, f + 1), stat, errmsg)
      end do
   end subroutine fill_record

end module fold_driver
