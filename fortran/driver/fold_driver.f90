!> The run driver: reads a run file, advances the particles, appends the results.
!>
!> One step from t to t + dt:
!>   1. hydrodynamics, one of
!>      * jeffery (hydrodynamics = 0): v = u_mean(x), omega = the exact Jeffery step
!>        for constant G (`fold_jeffery_step`), for this rank's block of particles,
!>        then gathered;
!>      * stokes (hydrodynamics = 1): the rigid (V, omega) of every particle from the
!>        fictitious-domain Stokes solve of the configuration at t, with the sphere
!>        lubrication correction when on (`fold_stokes_step::stokes_rigid_velocities`,
!>        `fold_lubrication`; by the one solver the factory
!>        `fold_stokes_factory` makes from /setup/resolved/stokes_*; for the fft
!>        backend the grid is distributed over the ranks with FFTW-MPI when np > 1),
!>        combined in time by `fold_time_scheme`: explicit Euler (v_n) or
!>        Adams-Bashforth 2 (3/2 v_n - 1/2 v_{n-1}; first step Euler). The solve of the configuration at t + dt is made at the end
!>        of the step, so every record holds the bulk stress of the configuration at
!>        its own time; the AB2 history is the uncorrected (hydrodynamic) velocity,
!>        carried across a Lees-Edwards wrap with the same velocity jump. A cell with
!>        walls (Couette) has neither offset nor wrap in y: its walls go to the
!>        solver settings (stokes_setup) and the backend imposes them;
!>   2. contacts: the seed's collision strategy on (v, omega) at the predicted
!>      configuration (`fold_contacts::resolve_contacts`, corrections summed over ranks
!>      after every sweep);
!>   3. exact rigid update (`fold_kinematics::rigid_update`), positions wrapped into
!>      the Lees-Edwards cell at t + dt;
!>   4. blow-up checks (a particle moving more than half the cell in one step;
!>      NaN/infinity anywhere in x, p, v, omega), drift measures;
!>   5. statistics (`fold_orientation_stats`) and output every `output_every` steps,
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
!> record. Nothing here stops the program: the outcome is returned to `fold_run`.
module fold_driver
   use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use mpi_f08
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_IO_ERROR, FOLD_OVERLAP, FOLD_NUMERICAL, FOLD_NOT_CONVERGED
   use fold_particles, only: particle_set_t
   use fold_cell, only: cell_t, cell_init, cell_set_time, cell_wrap, cell_wall_speed, cell_deforming
   use fold_kinematics, only: rigid_update
   use fold_contacts, only: contact_config_t, contact_stats_t, resolve_contacts, FOLD_CONTACT_NONE
   use fold_orientation_stats, only: orientation_moments
   use fold_jeffery_step, only: jeffery_stepper_t, jeffery_stepper_init, jeffery_step_velocities
   use fold_h5, only: h5_start, h5_stop
   use fold_run_file, only: run_setup_t, read_run_file, FOLD_HYDRO_STOKES
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, FOLD_RIGIDITY_PENALTY, FOLD_RIGIDITY_EXACT, &
                                 stokes_backend_name
   use fold_stokes_factory, only: stokes_solver_create
   use fold_stokes_step, only: stokes_context_t, stokes_record_t, stokes_context_attach, stokes_context_destroy, &
                               stokes_rigid_velocities, stokes_context_lubrication
   use fold_stokes_trust, only: stokes_kappa_check, stokes_stress_check
   use fold_time_scheme, only: FOLD_AB2, scheme_velocity
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

   public :: run_driver, measure_gaps

contains

   !> Run (or resume) the simulation described by a run file, on MPI_COMM_WORLD.
   subroutine run_driver(path, resume, outcome)
      !> Run file (/setup/resolved and /initial present; results are appended)
      character(len=*), intent(in) :: path
      !> Continue from /checkpoint instead of starting from /initial
      logical, intent(in) :: resume
      type(run_outcome_t), intent(out) :: outcome

      type(run_setup_t) :: setup
      type(particle_set_t) :: parts, good
      type(cell_t) :: cell
      type(contact_config_t) :: cfg
      type(contact_stats_t) :: cstats
      type(jeffery_stepper_t) :: stepper
      type(stokes_context_t) :: ctx
      type(stokes_record_t) :: srec
      type(run_output_t) :: out
      type(run_record_t) :: rec
      integer :: rank, nranks, stat, s2
      character(len=msg_len) :: errmsg, m2
      integer(i8) :: step, step0, last_record, last_snapshot, progress_every
      !> Rank 0: step of the last record / checkpoint completely written (-1: none yet)
      integer(i8) :: whole_record, whole_checkpoint
      integer(ip) :: first, last
      integer, allocatable :: cnt_v(:), dsp_v(:), cnt_w(:), dsp_w(:)
      real(dp) :: t
      !> Cost of the time loop (printed at its end): clock ticks, CPU seconds of this
      !> process, CG iterations of the solves made in the loop
      integer(i8) :: tick0, tick1, tick_rate, cg_total
      real(dp) :: cpu0, cpu1
      logical :: stokes, have_prev, good_have_prev
      !> Stokes velocities of the current configuration, of the previous one (AB2 history)
      real(dp), allocatable :: v_hyd(:, :), w_hyd(:, :), v_prev(:, :), w_prev(:, :), good_vprev(:, :), good_wprev(:, :)
      !> Solve re-use (stokes_solve_every = k > 1): v_hyd, w_hyd are the last solve (time
      !> t_a), v_sb, w_sb the one before (t_b, when have_b); the hydrodynamic velocity
      !> at a step's time is their linear extrapolation (v_hyd itself when k = 1)
      real(dp), allocatable :: v_sb(:, :), w_sb(:, :), v_est(:, :), w_est(:, :)
      real(dp) :: t_a, t_b
      logical :: have_b
      !> The last stokes_solve failed the stress check (fold_stokes_trust)
      logical :: untrusted

      call MPI_Comm_rank(MPI_COMM_WORLD, rank)
      call MPI_Comm_size(MPI_COMM_WORLD, nranks)
      call h5_start(stat, errmsg)
      if (stat /= FOLD_OK) then
         call finish_early(.false.)
         return
      end if

      ! ---------------------------------------------------------------- setup
      call read_run_file(path, setup, parts, stat, errmsg)
      if (stat == FOLD_OK) call make_cell(setup, cell, stat, errmsg)
      if (stat == FOLD_OK) then
         cfg = contact_config_t(mode=setup%collisions, alpha=setup%alpha, max_iter=setup%contact_max_iter, &
                                on_cap=setup%on_contact_cap, lubrication=setup%lubrication)
         call jeffery_stepper_init(stepper, parts, cell%G, setup%dt, stat, errmsg)
      end if
      ! A measuring pass now turns a cell too small for the contact search into a
      ! run-file error instead of a failure at step 1.
      if (stat == FOLD_OK) call measure_gaps(cell, parts, cfg, cstats, stat, errmsg)
      if (stat /= FOLD_OK) then
         call finish_early(.true.)
         return
      end if
      stokes = setup%hydrodynamics == FOLD_HYDRO_STOKES
      have_prev = .false.
      if (stokes) then
         call stokes_setup(setup, ctx, stat, errmsg)
         if (stat /= FOLD_OK) then
            call finish_early(stat == FOLD_INPUT_ERROR)
            return
         end if
         call stokes_context_lubrication(ctx, setup%lubrication, setup%alpha)
         allocate (v_hyd(parts%dim, parts%n), w_hyd(3, parts%n), v_prev(parts%dim, parts%n), w_prev(3, parts%n))
         allocate (v_sb(parts%dim, parts%n), w_sb(3, parts%n), v_est(parts%dim, parts%n), w_est(3, parts%n))
         v_sb = 0.0_dp
         w_sb = 0.0_dp
         have_b = .false.
         t_a = 0.0_dp
         t_b = 0.0_dp
         v_prev = 0.0_dp
         w_prev = 0.0_dp
         good_vprev = v_prev
         good_wprev = w_prev
         if (rank == 0) then
            ! one "x" between counts: a format with more descriptors than counts would end in "x"
            if (parts%dim == 2) then
               write (m2, '(i0,"x",i0)') setup%stokes_grid(1:2)
            else
               write (m2, '(i0,"x",i0,"x",i0)') setup%stokes_grid(1:3)
            end if
            m2 = trim(m2)//" ("//stokes_backend_name(setup%stokes%backend)//")"
            if (setup%stokes%rigidity == FOLD_RIGIDITY_EXACT) then
               write (output_unit, '(a,a,a,i0,a,es9.2,a,a)') "fold_run: Stokes grid ", trim(m2), " on ", nranks, &
                  " rank(s), exact rigidity, tol ", setup%stokes%tol, ", ", &
                  trim(merge("Adams-Bashforth 2", "explicit Euler   ", setup%time_scheme == FOLD_AB2))
            else
               write (output_unit, '(a,a,a,i0,a,es9.2,a,es9.2,a,a)') "fold_run: Stokes grid ", trim(m2), " on ", &
                  nranks, " rank(s), kappa ", setup%stokes%kappa, ", tol ", setup%stokes%tol, ", ", &
                  trim(merge("Adams-Bashforth 2", "explicit Euler   ", setup%time_scheme == FOLD_AB2))
            end if
         end if
      end if
      if (setup%lubrication .and. .not. stokes .and. rank == 0) write (output_unit, '(a)') &
         "fold_run: note: lubrication = 1 acts with the Stokes solver only (docs/physics.md#lubrication-between-spheres)"

      first = int(int(rank, i8)*parts%n/nranks + 1, ip)
      last = int(int(rank + 1, i8)*parts%n/nranks, ip)
      allocate (cnt_v(nranks), dsp_v(nranks), cnt_w(nranks), dsp_w(nranks))
      block
         integer :: r
         do r = 0, nranks - 1
            dsp_v(r + 1) = int(int(r, i8)*parts%n/nranks)
            cnt_v(r + 1) = int(int(r + 1, i8)*parts%n/nranks) - dsp_v(r + 1)
         end do
      end block
      dsp_w = 3*dsp_v
      cnt_w = 3*cnt_v
      dsp_v = parts%dim*dsp_v
      cnt_v = parts%dim*cnt_v

      ! ---------------------------------------------------------------- output
      call record_init(rec, parts%dim, setup%n_families)
      ! Every rank has closed the run file: rank 0 may now open it for writing
      ! (HDF5 file locks refuse a writer while readers hold the file).
      call MPI_Barrier(MPI_COMM_WORLD)
      step0 = 0
      t = 0.0_dp
      whole_record = -1
      whole_checkpoint = -1
      if (rank == 0) then
         if (resume) then
            if (stokes) then
               call output_resume(out, path, parts, setup%n_families, nranks, step0, t, stat, errmsg, stokes, &
                                  v_prev, w_prev, have_prev, lubrication=setup%lubrication)
            else
               call output_resume(out, path, parts, setup%n_families, nranks, step0, t, stat, errmsg)
            end if
         else
            call output_open(out, path, parts, setup%n_families, nranks, stat, errmsg, stokes, setup%lubrication)
         end if
      end if
      call share_status(stat, errmsg)
      if (stat /= FOLD_OK) then
         if (rank == 0) then
            if (stat == FOLD_IO_ERROR) then
               call output_abandon(out, s2, m2)  ! a write failed: close without writing more
            else
               call output_close(out, s2, m2)
            end if
         end if
         if (stat == FOLD_IO_ERROR) errmsg = "I/O: preparing the results in "//path//" failed: "//trim(errmsg)
         call finish_early(stat == FOLD_INPUT_ERROR)
         return
      end if
      if (resume) then
         whole_checkpoint = step0
         call MPI_Bcast(step0, 1, MPI_INTEGER8, 0, MPI_COMM_WORLD)
         call MPI_Bcast(t, 1, MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(parts%x, size(parts%x), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(parts%p, size(parts%p), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(parts%v, size(parts%v), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         call MPI_Bcast(parts%omega, size(parts%omega), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         if (stokes) then
            call MPI_Bcast(have_prev, 1, MPI_LOGICAL, 0, MPI_COMM_WORLD)
            call MPI_Bcast(v_prev, size(v_prev), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
            call MPI_Bcast(w_prev, size(w_prev), MPI_DOUBLE_PRECISION, 0, MPI_COMM_WORLD)
         end if
         ! positions at the checkpoint time (not the initial ones) decide the first gaps
         call measure_gaps(cell, parts, cfg, cstats, stat, errmsg)
      end if
      call reset_record(rec)
      call accumulate(rec, cstats, parts)
      last_record = -1
      last_snapshot = -1
      if (resume) then
         last_record = step0
         last_snapshot = step0
      end if
      good = parts
      if (stokes) then
         ! flow of the starting configuration: velocities of the first step, stress of its record
         call cell_set_time(cell, t)
         call stokes_solve(stat, errmsg)
         t_a = t
         if (stat /= FOLD_OK) then
            if (untrusted) then
               ! the starting configuration has no trusted stress: its record reads NaN
               rec%stress = ieee_value(1.0_dp, ieee_quiet_nan)
               rec%effective_viscosity = ieee_value(1.0_dp, ieee_quiet_nan)
            end if
            call fail(step0 + 1, trim(errmsg), stat)
            return
         end if
      end if
      if (.not. resume) then
         call write_outputs(0_i8, 0.0_dp, .true.)
         if (stat /= FOLD_OK) then
            call fail_io(0_i8, errmsg)
            return
         end if
      end if
      last_record = step0
      last_snapshot = step0
      call reset_record(rec)

      ! ---------------------------------------------------------------- time loop
      progress_every = max(1_i8, setup%nsteps/100)
      cg_total = 0
      call system_clock(tick0, tick_rate)
      call cpu_time(cpu0)
      good = parts
      do step = step0 + 1, setup%nsteps
         good%x = parts%x
         good%p = parts%p
         good%v = parts%v
         good%omega = parts%omega
         if (stokes) then
            good_vprev = v_prev
            good_wprev = w_prev
            good_have_prev = have_prev
         end if
         t = real(step - 1, dp)*setup%dt
         call cell_set_time(cell, t)

         if (stokes) then
            ! v_hyd: the solve of this configuration (made at the end of the previous step);
            ! with solve re-use, the extrapolation of the last two solves to this time
            if (setup%stokes_solve_every > 1 .and. have_b .and. t > t_a) then
               v_est = v_hyd + ((t - t_a)/(t_a - t_b))*(v_hyd - v_sb)
               w_est = w_hyd + ((t - t_a)/(t_a - t_b))*(w_hyd - w_sb)
            else
               v_est = v_hyd
               w_est = w_hyd
            end if
            call scheme_velocity(setup%time_scheme, have_prev, v_est, v_prev, parts%v)
            call scheme_velocity(setup%time_scheme, have_prev, w_est, w_prev, parts%omega)
            v_prev = v_est
            w_prev = w_est
            have_prev = .true.
         else
            call jeffery_step_velocities(stepper, cell, parts, first, last)
            if (nranks > 1) then
               call MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_DATATYPE_NULL, parts%v, cnt_v, dsp_v, MPI_DOUBLE_PRECISION, &
                                   MPI_COMM_WORLD)
               call MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_DATATYPE_NULL, parts%omega, cnt_w, dsp_w, &
                                   MPI_DOUBLE_PRECISION, MPI_COMM_WORLD)
            end if
         end if
         if (nranks > 1) then
            call resolve_contacts(cell, parts, setup%dt, cfg, cstats, stat, errmsg, first, last, reduce_world)
         else
            call resolve_contacts(cell, parts, setup%dt, cfg, cstats, stat, errmsg)
         end if
         if (stat /= FOLD_OK) then
            call fail(step, trim(errmsg), stat)
            return
         end if

         ! A particle crossing more than half the cell in one step makes the minimum
         ! image (and so every gap) meaningless: a blow-up, not a result.
         block
            real(dp) :: jump
            integer(ip) :: kmax
            character(len=200) :: why
            jump = 0.0_dp
            kmax = 0
            if (parts%n > 0) then
               kmax = int(maxloc(norm2(parts%v, dim=1), dim=1), ip)
               jump = norm2(parts%v(:, kmax))*setup%dt
            end if
            if (.not. (jump <= 0.5_dp*minval(setup%cell_lengths(1:parts%dim)))) then
               write (why, '(a,i0,a,es10.3,a)') "particle ", kmax - 1, " would move ", jump, &
                  " in one step, more than half the cell; dt too large"
               call fail(step, trim(why), FOLD_NUMERICAL)
               return
            end if
         end block
         call rigid_update(parts, setup%dt)
         t = real(step, dp)*setup%dt
         call cell_set_time(cell, t)
         block
            integer(ip) :: k
            real(dp) :: xk(3)
            real(dp), allocatable :: xw(:, :)
            if (stokes .and. setup%stokes_solve_every > 1) xw = parts%x
            do k = 1, parts%n
               xk(1:parts%dim) = parts%x(:, k)
               call cell_wrap(cell, parts%x(:, k), parts%v(:, k))
               ! the AB2 history crosses a sheared face with the same velocity jump
               if (stokes) call cell_wrap(cell, xk(1:parts%dim), v_prev(:, k))
               if (stokes .and. setup%stokes_solve_every > 1) then
                  ! so do the re-used solves
                  xk(1:parts%dim) = xw(1:parts%dim, k)
                  call cell_wrap(cell, xk(1:parts%dim), v_hyd(:, k))
                  xk(1:parts%dim) = xw(1:parts%dim, k)
                  call cell_wrap(cell, xk(1:parts%dim), v_sb(:, k))
               end if
            end do
         end block
         if (.not. finite_state(parts)) then
            call fail(step, "NaN or infinity in the particle state (x, p, v or omega); dt too large?", &
                      FOLD_NUMERICAL)
            return
         end if
         call accumulate(rec, cstats, parts)
         if (stokes .and. mod(step, int(setup%stokes_solve_every, i8)) == 0) then
            ! flow of the new configuration: the stress of this record, the velocities of the next step
            ! (with solve re-use every k-th step only; the last solve becomes the one before)
            if (setup%stokes_solve_every > 1) then
               v_sb = v_hyd
               w_sb = w_hyd
               t_b = t_a
               have_b = .true.
               t_a = t
            end if
            call stokes_solve(stat, errmsg)
            if (stat /= FOLD_OK .and. untrusted) then
               ! the stress of this step's record is not a result: the step fails, the
               ! state before it (good, its record already trusted) is kept
               call fail(step, trim(errmsg), stat)
               return
            end if
            if (stat /= FOLD_OK) then
               ! the configuration at t is good; it is the next step that cannot be made
               good%x = parts%x
               good%p = parts%p
               good%v = parts%v
               good%omega = parts%omega
               good_vprev = v_prev
               good_wprev = w_prev
               good_have_prev = have_prev
               call fail(step + 1, trim(errmsg), stat)
               return
            end if
         end if

         call write_outputs(step, t, step == setup%nsteps)
         if (stat /= FOLD_OK) then
            call fail_io(step, errmsg)
            return
         end if
         if (rank == 0 .and. (mod(step, progress_every) == 0 .or. step == setup%nsteps)) then
            write (output_unit, '(a,1x,i0,1x,i0,1x,es23.16)') "PROGRESS", step, setup%nsteps, t
            flush (output_unit)
         end if
      end do

      call cpu_time(cpu1)
      call system_clock(tick1)
      if (rank == 0) then
         ! benchmarks/bench_stokes_step.py reads this line
         write (output_unit, '(a,i0,a,es12.5,a,es12.5,a,i0)') "TIMING steps=", setup%nsteps - step0, &
            " wall=", real(tick1 - tick0, dp)/real(max(tick_rate, 1_i8), dp), " cpu=", cpu1 - cpu0, &
            " cg_iterations=", cg_total
         flush (output_unit)
      end if
      if (rank == 0) then
         call output_status(out, "ok", setup%nsteps, stat, errmsg)
         if (stat == FOLD_OK) then
            call output_close(out, stat, errmsg)
         else
            ! a failed flush: close without writing more (status stays "running")
            call output_abandon(out, s2, m2)
         end if
      end if
      call share_status(stat, errmsg)
      call stokes_context_destroy(ctx)
      outcome%stat = stat
      outcome%steps_done = setup%nsteps
      outcome%time = t
      if (stat /= FOLD_OK) then
         ! every step is computed and written; only the final status or the close failed
         write (m2, '(a,i0,a)') "I/O: recording the end of the run (step ", setup%nsteps, ") failed: "
         outcome%errmsg = trim(m2)//" "//trim(errmsg)// &
                          "; the records and the checkpoint are whole, but the status attribute may still read 'running'"
      end if
      call h5_stop()

   contains

      !> Record / snapshot / checkpoint due at this step (rank 0 writes; all ranks
      !> learn the status).
      subroutine write_outputs(st, time, final)
         integer(i8), intent(in) :: st
         real(dp), intent(in) :: time
         logical, intent(in) :: final
         stat = FOLD_OK
         errmsg = ""
         if (rank == 0) then
            if (mod(st, setup%output_every) == 0 .or. final) then
               call fill_record(rec, st, time, parts, setup%n_families)
               call output_record(out, rec, stat, errmsg)
               if (stat == FOLD_OK) then
                  call reset_record(rec)
                  whole_record = st
               end if
            end if
            if (stat == FOLD_OK .and. setup%snapshot_every > 0) then
               if (mod(st, setup%snapshot_every) == 0 .or. final) &
                  call output_snapshot(out, st, time, parts, stat, errmsg)
            end if
            if (stat == FOLD_OK .and. setup%checkpoint_every > 0) then
               if (mod(st, setup%checkpoint_every) == 0 .or. final) then
                  call checkpoint(st, time, stat, errmsg)
                  if (stat == FOLD_OK) whole_checkpoint = st
               end if
            end if
         end if
         if (mod(st, setup%output_every) == 0 .or. final) then
            last_record = st
            call reset_record(rec)
         end if
         if (setup%snapshot_every > 0) then
            if (mod(st, setup%snapshot_every) == 0 .or. final) last_snapshot = st
         end if
         call share_status(stat, errmsg)
      end subroutine write_outputs

      !> Write /checkpoint (with the AB2 history of a Stokes run).
      subroutine checkpoint(st, time, cstat, cmsg)
         integer(i8), intent(in) :: st
         real(dp), intent(in) :: time
         integer, intent(out) :: cstat
         character(len=msg_len), intent(out) :: cmsg
         if (stokes .and. have_prev) then
            call output_checkpoint(out, st, time, parts, cstat, cmsg, v_prev, w_prev)
         else
            call output_checkpoint(out, st, time, parts, cstat, cmsg)
         end if
      end subroutine checkpoint

      !> Stokes solve of the current configuration (all ranks): v_hyd, w_hyd and the
      !> solver/stress part of the record; parts%v, parts%omega are left as they were.
      subroutine stokes_solve(sstat, smsg)
         integer, intent(out) :: sstat
         character(len=msg_len), intent(out) :: smsg
         v_hyd = parts%v
         w_hyd = parts%omega
         call stokes_rigid_velocities(ctx, cell, parts, srec, sstat, smsg)
         ! swap: the fitted rigid velocities go to v_hyd, parts keeps its step velocities
         block
            real(dp), allocatable :: tmp(:, :)
            tmp = parts%v
            parts%v = v_hyd
            v_hyd = tmp
            tmp = parts%omega
            parts%omega = w_hyd
            w_hyd = tmp
         end block
         untrusted = .false.
         if (sstat == FOLD_OK) then
            call stokes_stress_check(srec%bulk%eta_eff, setup%stokes%eta_f, product(int(setup%stokes_grid, i8)), &
                                     setup%stokes%kappa, setup%stokes%tol, sstat, smsg)
            untrusted = sstat /= FOLD_OK
            if (untrusted) then
               ! no number of this solve goes into a record
               smsg = "Stokes solve: "//trim(smsg)
               return
            end if
         end if
         if (sstat == FOLD_OK .or. sstat == FOLD_NOT_CONVERGED) then
            cg_total = cg_total + srec%iterations
            rec%stokes_iterations = max(rec%stokes_iterations, int(srec%iterations, i8))
            rec%stokes_residual = max(rec%stokes_residual, srec%residual)
            rec%rigidity_max = max(rec%rigidity_max, srec%rigidity_max)
            rec%rigidity_mean = max(rec%rigidity_mean, srec%rigidity_mean)
            rec%stress = srec%bulk%sigma(1:parts%dim, 1:parts%dim)
            rec%effective_viscosity = srec%bulk%eta_eff
            rec%lubricated_pairs = max(rec%lubricated_pairs, int(srec%lub%pairs, i8))
            rec%lubrication_correction = max(rec%lubrication_correction, srec%lub%max_correction)
         end if
         if (sstat == FOLD_OK) then
            if (.not. (all(abs(v_hyd) <= huge(1.0_dp)) .and. all(abs(w_hyd) <= huge(1.0_dp)))) then
               sstat = FOLD_NUMERICAL
               smsg = "Stokes solve gave NaN or infinite particle velocities"
            end if
         else
            smsg = "Stokes solver: "//trim(smsg)
         end if
      end subroutine stokes_solve

      !> Stop at `failed_step`: restore the last good state, write it, set status.
      subroutine fail(failed_step, cause, code)
         integer(i8), intent(in) :: failed_step
         character(len=*), intent(in) :: cause
         integer, intent(in) :: code
         integer(i8) :: good_step
         real(dp) :: good_t
         character(len=msg_len) :: text
         integer :: ws

         good_step = failed_step - 1
         good_t = real(good_step, dp)*setup%dt
         if (good_step >= 0 .and. allocated(good%x)) then
            parts%x = good%x
            parts%p = good%p
            parts%v = good%v
            parts%omega = good%omega
            if (stokes) then
               v_prev = good_vprev
               w_prev = good_wprev
               have_prev = good_have_prev
            end if
         end if
         write (text, '(a,i0,a,es23.16,a,a)') "failed: step ", failed_step, ", t = ", &
            real(failed_step, dp)*setup%dt, ": ", trim(cause)
         ws = FOLD_OK
         m2 = ""
         if (rank == 0 .and. out%file >= 0) then
            ! Each write only after the previous one succeeded: a file that refuses one
            ! (full disk) is not written into further, apart from the status (best effort).
            if (last_record /= good_step .and. good_step >= 0) then
               call fill_record(rec, good_step, good_t, parts, setup%n_families)
               call output_record(out, rec, ws, m2)
            end if
            if (ws == FOLD_OK .and. last_snapshot /= good_step .and. good_step >= 0) &
               call output_snapshot(out, good_step, good_t, parts, ws, m2)
            if (ws == FOLD_OK .and. good_step >= 0) call checkpoint(good_step, good_t, ws, m2)
            if (ws /= FOLD_OK) text = trim(text)//"; writing the last good state failed too: I/O: "//trim(m2)
            call record_status(text, max(good_step, 0_i8), ws == FOLD_OK)
         end if
         outcome%stat = code
         outcome%errmsg = text
         outcome%steps_done = max(good_step, 0_i8)
         outcome%time = good_t
         call stokes_context_destroy(ctx)
         call h5_stop()
      end subroutine fail

      !> Stop after the outputs of step `st` could not be written (`cause`: the first
      !> failed HDF5 call, naming the dataset). Nothing more is written into the file but
      !> the status (best effort: on a full disk that may fail too, and stderr says so):
      !> the whole records and snapshots (records_complete, snapshots_complete) and the
      !> last complete checkpoint stay as they are, so readers and --resume see the
      !> last good state. steps_done = the step of the last whole record.
      subroutine fail_io(st, cause)
         integer(i8), intent(in) :: st
         character(len=*), intent(in) :: cause
         character(len=msg_len) :: text
         integer(i8) :: kept

         write (text, '(a,i0,a,es23.16,a,i0,a,a)') "failed: step ", st, ", t = ", real(st, dp)*setup%dt, &
            ": I/O: writing the outputs of step ", st, " failed: ", trim(cause)
         kept = max(whole_record, 0_i8)
         if (rank == 0) then
            if (whole_record >= 0) then
               write (m2, '(a,i0)') "; the file keeps the whole records up to step ", whole_record
            else if (resume) then
               m2 = "; the file keeps the whole records written before this resume"
               kept = step0
            else
               m2 = "; no record of this run is complete in the file"
            end if
            if (whole_checkpoint >= 0) write (m2, '(a,a,i0,a)') trim(m2), " and the checkpoint of step ", &
               whole_checkpoint, " (continue with --resume once there is space)"
            text = trim(text)//trim(m2)
            if (out%file >= 0) call record_status(text, kept, .false.)
         end if
         call MPI_Bcast(text, msg_len, MPI_CHARACTER, 0, MPI_COMM_WORLD)
         outcome%stat = FOLD_IO_ERROR
         outcome%errmsg = text
         call MPI_Bcast(kept, 1, MPI_INTEGER8, 0, MPI_COMM_WORLD)
         outcome%steps_done = kept
         outcome%time = real(outcome%steps_done, dp)*setup%dt
         call stokes_context_destroy(ctx)
         call h5_stop()
      end subroutine fail_io

      !> Rank 0: set `status` and `steps_done`, flush and close the file; stderr says so
      !> when that failed (the status then reads "running", or is missing).
      subroutine record_status(text, done, clean)
         character(len=*), intent(in) :: text
         integer(i8), intent(in) :: done
         !> Every write so far succeeded (else the file is closed without writing more
         !> into it and reopened for the status: output_failed_status)
         logical, intent(in) :: clean
         integer :: ss, sc
         character(len=msg_len) :: ms, mc
         if (clean) then
            call output_status(out, trim(text), done, ss, ms)
            if (ss == FOLD_OK) then
               call output_close(out, ss, ms)
            else
               call output_abandon(out, sc, mc)  ! the flush failed: close without writing more
               if (sc /= FOLD_OK) ms = trim(ms)//"; "//trim(mc)
            end if
         else
            call output_failed_status(out, path, trim(text), done, ss, ms)
         end if
         if (ss /= FOLD_OK) then
            write (error_unit, '(a)') "fold_run: the failure could not be recorded in "//path// &
               " (status attribute: I/O: "//trim(ms)//"); its status attribute may still read 'running'"
            flush (error_unit)
         end if
      end subroutine record_status

      !> Return before any step: rejected run file or unusable output file.
      subroutine finish_early(input_problem)
         logical, intent(in) :: input_problem
         outcome%stat = stat
         outcome%errmsg = errmsg
         outcome%bad_input = input_problem
         call h5_stop()
      end subroutine finish_early

   end subroutine run_driver

   !> Stokes solver of a run (fold_stokes_factory, on MPI_COMM_WORLD) from the settings
   !> of /setup/resolved.
   subroutine stokes_setup(setup, ctx, stat, errmsg)
      type(run_setup_t), intent(in) :: setup
      type(stokes_context_t), intent(inout) :: ctx
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      class(stokes_solver_t), allocatable :: solver
      type(stokes_settings_t) :: set
      integer :: envstat

      ! walls are a property of the cell (fold_cell): the backend imposes them when set
      set = setup%stokes
      set%walls = setup%walls
      ! the kappa the solver can carry at this grid, tolerance and precision
      ! (fold_stokes_trust); FOLD_RUN_UNCHECKED_KAPPA set in the environment waives it, for
      ! the test of the run-time stress check only (tests/micro/test_stokes_trust.py)
      call get_environment_variable("FOLD_RUN_UNCHECKED_KAPPA", status=envstat)
      if (envstat /= 0 .and. set%rigidity == FOLD_RIGIDITY_PENALTY) then
         call stokes_kappa_check(set, product(int(setup%stokes_grid, i8)), stat, errmsg)
         if (stat /= FOLD_OK) then
            errmsg = "/setup/resolved/stokes_kappa: "//trim(errmsg)
            return
         end if
      end if
      call stokes_solver_create(set, setup%dim, setup%stokes_grid, MPI_COMM_WORLD, solver, stat, errmsg)
      if (stat /= FOLD_OK) then
         errmsg = "/setup/resolved/stokes_*: "//trim(errmsg)
         return
      end if
      call stokes_context_attach(ctx, solver)
   end subroutine stokes_setup

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
      type(contact_config_t) :: look

      still = parts
      still%v = 0.0_dp
      still%omega = 0.0_dp
      look = cfg
      look%mode = FOLD_CONTACT_NONE
      call resolve_contacts(cell, still, tiny(1.0_dp), look, cstats, stat, errmsg)
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
