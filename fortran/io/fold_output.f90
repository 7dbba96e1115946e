!> Results of a run, appended to the run file at its root in a netCDF-compatible
!> layout (dimension scales; `xarray.open_dataset(path, engine="h5netcdf")`).
!>
!> Dimensions (Python order as h5py/xarray see them):
!>   `time` (growing; values = t [s]), `i`, `j`, `k`, `l`, `xyz` (size dim; values
!>   0 ... dim-1), `family` (values 0 ... nfam-1, names in /setup/resolved/family_names),
!>   `snapshot` (growing; values = step number), `particle` (values 0 ... n-1).
!> Variables: `step(time)`, `a2(time,i,j)`, `a4(time,i,j,k,l)`,
!>   `a2_family(time,family,i,j)`, `a4_family(time,family,i,j,k,l)`, contact and
!>   drift records over time (see `run_record_t`), `snapshot_time(snapshot)`,
!>   `x(snapshot,particle,xyz)`, `p(snapshot,particle,xyz)`.
!> A record summarises the steps since the previous record: minima of gaps,
!>   maxima of iteration counts, pairs left and drifts, sums of corrections, so
!>   "min gap >= 0 at every step" can be checked from any output interval.
!> Stokes runs (output_open(..., stokes=.true.)) add `stokes_iterations(time)`,
!>   `stokes_residual(time)`, `rigidity_max(time)`, `rigidity_mean(time)` (worst over
!>   the interval), `stress(time,i,j)` [Pa] and `effective_viscosity(time)` [Pa s] (the
!>   configuration at the record time).
!> `/checkpoint`: latest full state (`step`, `time`, `x`, `p`, `v`, `omega`; Stokes
!>   runs: the Adams-Bashforth history `v_hydro_prev`, `omega_hydro_prev`) for
!>   `fold_run --resume`.
!> Root attributes written here: `mpi_ranks`, `fortran_creator`, `status`
!>   ("running", "ok" or "failed: step ..., t = ...: cause"), `steps_done`.
!> Only one process (MPI rank 0) may hold a run_output_t open.
module fold_output
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_IO_ERROR
   use fold_version, only: fold_version_string, fold_git_revision
   use fold_particles, only: particle_set_t
   use fold_h5, only: hid_t, hsize_t, FOLD_H5_REAL, FOLD_H5_INT, h5_open_file, h5_close_file, h5_flush, &
                      h5_exists, h5_read_int, h5_read_real, h5_read_int_array, h5_read_real_array, &
                      h5_attr_string, h5_attr_int, h5_make_group, h5_delete, h5_scale_int, h5_scale_real, &
                      h5_var_create, h5_var_append_real, h5_var_append_int, h5_var_length, h5_var_truncate, &
                      h5_write_real_array, h5_write_int_scalar, h5_write_real_scalar
   implicit none
   private

   !> What is recorded on the `time` axis (aggregated over the steps since the last record).
   type, public :: run_record_t
      !> Step number (0 = initial state)
      integer(i8) :: step = 0
      !> Time [s]
      real(dp) :: time = 0.0_dp
      !> Orientation tensors of all particles a2(dim,dim), a4(dim,dim,dim,dim) [-]
      real(dp), allocatable :: a2(:, :), a4(:, :, :, :)
      !> Per family a2(dim,dim,nfam), a4(dim,dim,dim,dim,nfam) [-] (zero for an empty family)
      real(dp), allocatable :: a2_family(:, :, :), a4_family(:, :, :, :, :)
      !> Contact velocity corrections applied (sum over the interval)
      integer(i8) :: n_corrections = 0
      !> Contact loop iterations (maximum per step over the interval)
      integer(i8) :: contact_iterations = 0
      !> Pairs still closer than alpha after the contact loop (maximum over the interval)
      integer(i8) :: pairs_left = 0
      !> Steps in the interval whose contact loop reached its iteration cap
      integer(i8) :: capped_steps = 0
      !> Smallest surface gap after the step (minimum over the interval) [m]
      real(dp) :: min_gap = huge(1.0_dp)
      !> min_gap / alpha (minimum over the interval) [-]
      real(dp) :: min_gap_over_alpha = huge(1.0_dp)
      !> max_k | |X2 - X1| - L_k | / L_k with end points X = x +- (L/2) p (maximum) [-]
      real(dp) :: length_drift = 0.0_dp
      !> max_k | |p_k| - 1 | (maximum over the interval) [-]
      real(dp) :: unit_norm_drift = 0.0_dp
      ! ---- Stokes runs only: solver records (worst over the interval) and the bulk
      ! stress of the configuration at the record time
      !> CG iterations of a solve (maximum over the interval)
      integer(i8) :: stokes_iterations = 0
      !> Relative preconditioned residual reached (maximum over the interval) [-]
      real(dp) :: stokes_residual = 0.0_dp
      !> Largest per-particle rigidity residual (maximum over the interval) [-]
      real(dp) :: rigidity_max = 0.0_dp
      !> Mean over the particles of the rigidity residual (maximum over the interval) [-]
      real(dp) :: rigidity_mean = 0.0_dp
      !> Deviatoric bulk stress <2 eta eps(u)> (dim, dim) at the record time [Pa]
      real(dp), allocatable :: stress(:, :)
      !> Effective viscosity Sigma':E / (2 E:E) (= Sigma_xy/gamma_dot in shear) at the record time [Pa s]
      real(dp) :: effective_viscosity = 0.0_dp
   end type run_record_t

   !> An open run file receiving results.
   type, public :: run_output_t
      integer(hid_t) :: file = -1
      integer(ip) :: dim = 3, n = 0, n_families = 1
      !> Records / snapshots written so far
      integer(hsize_t) :: n_records = 0, n_snapshots = 0
      !> Stokes hydrodynamics: solver and stress records are written
      logical :: stokes = .false.
   end type run_output_t

   public :: output_open, output_resume, output_record, output_snapshot, output_checkpoint, output_status, &
             output_close, record_init

   character(len=*), parameter :: SCALAR_VARS(9) = [character(len=24) :: "step", "n_corrections", &
      "contact_iterations", "pairs_left", "capped_steps", "min_gap", "min_gap_over_alpha", &
      "length_drift", "unit_norm_drift"]
   !> Time series of Stokes runs only (besides `stress`)
   character(len=*), parameter :: STOKES_VARS(5) = [character(len=24) :: "stokes_iterations", "stokes_residual", &
      "rigidity_max", "rigidity_mean", "effective_viscosity"]

contains

   !> Allocate the tensors of a record for dimension dim and nfam families.
   subroutine record_init(rec, dim, nfam)
      type(run_record_t), intent(out) :: rec
      integer(ip), intent(in) :: dim, nfam
      allocate (rec%a2(dim, dim), rec%a4(dim, dim, dim, dim), rec%a2_family(dim, dim, nfam), &
                rec%a4_family(dim, dim, dim, dim, nfam), rec%stress(dim, dim))
      rec%stress = 0.0_dp
      rec%a2 = 0.0_dp
      rec%a4 = 0.0_dp
      rec%a2_family = 0.0_dp
      rec%a4_family = 0.0_dp
   end subroutine record_init

   !> Open a run file for writing and lay out the (empty) result variables.
   !> Refuses a file that already holds results (use output_resume).
   subroutine output_open(out, path, parts, n_families, mpi_ranks, stat, errmsg, stokes)
      type(run_output_t), intent(out) :: out
      character(len=*), intent(in) :: path
      type(particle_set_t), intent(in) :: parts
      integer(ip), intent(in) :: n_families
      !> Number of MPI processes of the run
      integer, intent(in) :: mpi_ranks
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> Stokes run: also lay out the solver and stress records (default .false.)
      logical, intent(in), optional :: stokes

      call h5_open_file(path, .true., out%file, stat, errmsg); if (stat /= FOLD_OK) return
      out%dim = parts%dim
      out%n = parts%n
      out%n_families = n_families
      if (present(stokes)) out%stokes = stokes
      if (h5_exists(out%file, "time")) then
         stat = FOLD_INPUT_ERROR
         errmsg = trim(path)//": /time exists, the file already holds results (run with --resume to continue)"
         return
      end if
      call layout(out, stat, errmsg); if (stat /= FOLD_OK) return
      call run_attributes(out, mpi_ranks, stat, errmsg)
   end subroutine output_open

   !> Reopen a run file at its checkpoint: returns the checkpoint state and step,
   !> and drops records and snapshots written after that step.
   subroutine output_resume(out, path, parts, n_families, mpi_ranks, step, time, stat, errmsg, stokes, &
                            v_prev, omega_prev, have_prev)
      type(run_output_t), intent(out) :: out
      character(len=*), intent(in) :: path
      !> In: the initial set (sizes, shapes); out: x, p, v, omega of the checkpoint
      type(particle_set_t), intent(inout) :: parts
      integer(ip), intent(in) :: n_families
      integer, intent(in) :: mpi_ranks
      !> Checkpoint step and time [s]
      integer(i8), intent(out) :: step
      real(dp), intent(out) :: time
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> Stokes run: its records are truncated too (default .false.)
      logical, intent(in), optional :: stokes
      !> Stokes velocities of the step before the checkpoint (Adams-Bashforth history),
      !> (dim, n) [m/s] and (3, n) [1/s]; have_prev = .false. when the checkpoint has none
      real(dp), intent(inout), optional :: v_prev(:, :), omega_prev(:, :)
      logical, intent(out), optional :: have_prev
      real(dp), allocatable :: buf(:)
      integer(i8), allocatable :: steps(:)
      integer(hsize_t) :: d, n, nrec, keep
      integer :: k

      step = 0
      time = 0.0_dp
      if (present(have_prev)) have_prev = .false.
      call h5_open_file(path, .true., out%file, stat, errmsg); if (stat /= FOLD_OK) return
      out%dim = parts%dim
      out%n = parts%n
      out%n_families = n_families
      if (present(stokes)) out%stokes = stokes
      if (.not. h5_exists(out%file, "/checkpoint/step")) then
         stat = FOLD_INPUT_ERROR
         errmsg = "/checkpoint/step: missing, nothing to resume from (set checkpoint_every > 0)"
         return
      end if
      d = int(parts%dim, hsize_t)
      n = int(parts%n, hsize_t)
      call h5_read_int(out%file, "/checkpoint/step", step, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_read_real(out%file, "/checkpoint/time", time, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_read_real_array(out%file, "/checkpoint/x", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      parts%x = reshape(buf, [parts%dim, parts%n])
      call h5_read_real_array(out%file, "/checkpoint/p", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      parts%p = reshape(buf, [parts%dim, parts%n])
      call h5_read_real_array(out%file, "/checkpoint/v", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) return
      parts%v = reshape(buf, [parts%dim, parts%n])
      call h5_read_real_array(out%file, "/checkpoint/omega", [3_hsize_t, n], buf, stat, errmsg)
      if (stat /= FOLD_OK) return
      parts%omega = reshape(buf, [3, parts%n])
      if (present(v_prev) .and. present(omega_prev) .and. present(have_prev)) then
         if (h5_exists(out%file, "/checkpoint/v_hydro_prev")) then
            call h5_read_real_array(out%file, "/checkpoint/v_hydro_prev", [d, n], buf, stat, errmsg)
            if (stat /= FOLD_OK) return
            v_prev = reshape(buf, [parts%dim, parts%n])
            call h5_read_real_array(out%file, "/checkpoint/omega_hydro_prev", [3_hsize_t, n], buf, stat, errmsg)
            if (stat /= FOLD_OK) return
            omega_prev = reshape(buf, [3, parts%n])
            have_prev = .true.
         end if
      end if

      ! Records are in step order: keep those up to the checkpoint.
      call h5_var_length(out%file, "step", nrec, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_read_int_array(out%file, "step", [nrec], steps, stat, errmsg); if (stat /= FOLD_OK) return
      keep = count(steps(1:nrec) <= step)
      call h5_var_truncate(out%file, "time", keep, stat, errmsg); if (stat /= FOLD_OK) return
      do k = 1, size(SCALAR_VARS)
         call h5_var_truncate(out%file, trim(SCALAR_VARS(k)), keep, stat, errmsg); if (stat /= FOLD_OK) return
      end do
      call h5_var_truncate(out%file, "a2", keep, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_truncate(out%file, "a4", keep, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_truncate(out%file, "a2_family", keep, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_truncate(out%file, "a4_family", keep, stat, errmsg); if (stat /= FOLD_OK) return
      if (out%stokes) then
         do k = 1, size(STOKES_VARS)
            call h5_var_truncate(out%file, trim(STOKES_VARS(k)), keep, stat, errmsg); if (stat /= FOLD_OK) return
         end do
         call h5_var_truncate(out%file, "stress", keep, stat, errmsg); if (stat /= FOLD_OK) return
      end if
      out%n_records = keep

      call h5_var_length(out%file, "snapshot", nrec, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_read_int_array(out%file, "snapshot", [nrec], steps, stat, errmsg); if (stat /= FOLD_OK) return
      keep = count(steps(1:nrec) <= step)
      call h5_var_truncate(out%file, "snapshot", keep, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_truncate(out%file, "snapshot_time", keep, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_truncate(out%file, "x", keep, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_truncate(out%file, "p", keep, stat, errmsg); if (stat /= FOLD_OK) return
      out%n_snapshots = keep
      call run_attributes(out, mpi_ranks, stat, errmsg)
   end subroutine output_resume

   !> Append one record on the time axis and flush the file.
   subroutine output_record(out, rec, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      type(run_record_t), intent(in) :: rec
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hsize_t) :: r

      r = out%n_records + 1
      call h5_var_append_real(out%file, "time", r, [rec%time], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_int(out%file, "step", r, [rec%step], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "a2", r, reshape(rec%a2, [size(rec%a2)]), stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "a4", r, reshape(rec%a4, [size(rec%a4)]), stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "a2_family", r, reshape(rec%a2_family, [size(rec%a2_family)]), stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "a4_family", r, reshape(rec%a4_family, [size(rec%a4_family)]), stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_int(out%file, "n_corrections", r, [rec%n_corrections], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_int(out%file, "contact_iterations", r, [rec%contact_iterations], stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_int(out%file, "pairs_left", r, [rec%pairs_left], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_int(out%file, "capped_steps", r, [rec%capped_steps], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "min_gap", r, [rec%min_gap], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "min_gap_over_alpha", r, [rec%min_gap_over_alpha], stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "length_drift", r, [rec%length_drift], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "unit_norm_drift", r, [rec%unit_norm_drift], stat, errmsg)
      if (stat /= FOLD_OK) return
      if (out%stokes) then
         call h5_var_append_int(out%file, "stokes_iterations", r, [rec%stokes_iterations], stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_var_append_real(out%file, "stokes_residual", r, [rec%stokes_residual], stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_var_append_real(out%file, "rigidity_max", r, [rec%rigidity_max], stat, errmsg); if (stat /= FOLD_OK) return
         call h5_var_append_real(out%file, "rigidity_mean", r, [rec%rigidity_mean], stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_var_append_real(out%file, "stress", r, reshape(rec%stress, [size(rec%stress)]), stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_var_append_real(out%file, "effective_viscosity", r, [rec%effective_viscosity], stat, errmsg)
         if (stat /= FOLD_OK) return
      end if
      out%n_records = r
      call h5_flush(out%file, stat, errmsg)
   end subroutine output_record

   !> Append a snapshot of positions and axes.
   subroutine output_snapshot(out, step, time, parts, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      integer(i8), intent(in) :: step
      real(dp), intent(in) :: time
      type(particle_set_t), intent(in) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hsize_t) :: r

      r = out%n_snapshots + 1
      call h5_var_append_int(out%file, "snapshot", r, [step], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "snapshot_time", r, [time], stat, errmsg); if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "x", r, reshape(parts%x, [size(parts%x)]), stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_append_real(out%file, "p", r, reshape(parts%p, [size(parts%p)]), stat, errmsg)
      if (stat /= FOLD_OK) return
      out%n_snapshots = r
      call h5_flush(out%file, stat, errmsg)
   end subroutine output_snapshot

   !> Replace /checkpoint with the given state.
   subroutine output_checkpoint(out, step, time, parts, stat, errmsg, v_prev, omega_prev)
      type(run_output_t), intent(inout) :: out
      integer(i8), intent(in) :: step
      real(dp), intent(in) :: time
      type(particle_set_t), intent(in) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> Stokes runs with a history: the Stokes velocities of the previous step
      !> (Adams-Bashforth), (dim, n) [m/s] and (3, n) [1/s]
      real(dp), intent(in), optional :: v_prev(:, :), omega_prev(:, :)
      integer(hsize_t) :: d, n

      d = int(parts%dim, hsize_t)
      n = int(parts%n, hsize_t)
      call h5_make_group(out%file, "/checkpoint", stat, errmsg); if (stat /= FOLD_OK) return
      ! The step is written last: a checkpoint whose step is missing is incomplete.
      call h5_delete(out%file, "/checkpoint/step", stat, errmsg); if (stat /= FOLD_OK) return
      call h5_write_real_scalar(out%file, "/checkpoint/time", time, "s", "time of the checkpoint", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_write_real_array(out%file, "/checkpoint/x", reshape(parts%x, [size(parts%x)]), [d, n], "m", &
                               "particle centres", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_write_real_array(out%file, "/checkpoint/p", reshape(parts%p, [size(parts%p)]), [d, n], "1", &
                               "particle unit axes", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_write_real_array(out%file, "/checkpoint/v", reshape(parts%v, [size(parts%v)]), [d, n], "m s-1", &
                               "particle velocities of the last step", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_write_real_array(out%file, "/checkpoint/omega", reshape(parts%omega, [size(parts%omega)]), [3_hsize_t, n], &
                               "s-1", "particle angular velocities of the last step", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_delete(out%file, "/checkpoint/v_hydro_prev", stat, errmsg); if (stat /= FOLD_OK) return
      call h5_delete(out%file, "/checkpoint/omega_hydro_prev", stat, errmsg); if (stat /= FOLD_OK) return
      if (present(v_prev) .and. present(omega_prev)) then
         call h5_write_real_array(out%file, "/checkpoint/v_hydro_prev", reshape(v_prev, [size(v_prev)]), [d, n], &
                                  "m s-1", "Stokes velocities of the step before the checkpoint (Adams-Bashforth history)", &
                                  stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_write_real_array(out%file, "/checkpoint/omega_hydro_prev", reshape(omega_prev, [size(omega_prev)]), &
                                  [3_hsize_t, n], "s-1", &
                                  "Stokes angular velocities of the step before the checkpoint (Adams-Bashforth history)", &
                                  stat, errmsg)
         if (stat /= FOLD_OK) return
      end if
      call h5_write_int_scalar(out%file, "/checkpoint/step", step, "step number of the checkpoint", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_flush(out%file, stat, errmsg)
   end subroutine output_checkpoint

   !> Set the root attributes `status` and `steps_done` and flush.
   subroutine output_status(out, status, steps_done, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      character(len=*), intent(in) :: status
      integer(i8), intent(in) :: steps_done
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_attr_string(out%file, "status", status, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_int(out%file, "steps_done", steps_done, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_flush(out%file, stat, errmsg)
   end subroutine output_status

   !> Close the file.
   subroutine output_close(out, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_close_file(out%file, stat, errmsg)
   end subroutine output_close

   ! ------------------------------------------------------------------ internals

   subroutine run_attributes(out, mpi_ranks, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      integer, intent(in) :: mpi_ranks
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_attr_int(out%file, "mpi_ranks", int(mpi_ranks, i8), stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_string(out%file, "fortran_creator", "fold_run "//fold_version_string//" ("// &
                          fold_git_revision//")", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_attr_string(out%file, "status", "running", stat, errmsg); if (stat /= FOLD_OK) return
      call h5_flush(out%file, stat, errmsg)
   end subroutine run_attributes

   !> Dimension scales and empty variables.
   subroutine layout(out, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hsize_t) :: d, n, f
      integer(i8) :: q
      integer(i8), allocatable :: axis(:)
      character(len=*), parameter :: T = "time"
      character(len=1), parameter :: ij(4) = ["i", "j", "k", "l"]
      integer :: k

      d = int(out%dim, hsize_t)
      n = int(out%n, hsize_t)
      f = int(out%n_families, hsize_t)
      call h5_scale_real(out%file, "time", [real(dp) ::], .true., "s", "time", stat, errmsg); if (stat /= FOLD_OK) return
      axis = [(q, q=0, d - 1)]
      do k = 1, 4
         call h5_scale_int(out%file, ij(k), axis, .false., "1", "tensor index "//ij(k)//" (0 = x, 1 = y, 2 = z)", &
                           stat, errmsg)
         if (stat /= FOLD_OK) return
      end do
      call h5_scale_int(out%file, "xyz", axis, .false., "1", "vector component (0 = x, 1 = y, 2 = z)", stat, errmsg)
      if (stat /= FOLD_OK) return
      axis = [(q, q=0, f - 1)]
      call h5_scale_int(out%file, "family", axis, .false., "1", &
                        "particle family (names in /setup/resolved/family_names)", stat, errmsg)
      if (stat /= FOLD_OK) return
      axis = [(q, q=0, n - 1)]
      call h5_scale_int(out%file, "particle", axis, .false., "1", "particle index (rows of /initial)", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_scale_int(out%file, "snapshot", [integer(i8) ::], .true., "1", "step number of the snapshot", &
                        stat, errmsg)
      if (stat /= FOLD_OK) return

      call series("step", FOLD_H5_INT, "1", "step number of the record"); if (stat /= FOLD_OK) return
      call h5_var_create(out%file, "a2", FOLD_H5_REAL, [character(len=8) :: "j", "i", T], [d, d, 0_hsize_t], .true., "1", &
                         "second-order orientation tensor <p p>", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_create(out%file, "a4", FOLD_H5_REAL, [character(len=8) :: "l", "k", "j", "i", T], [d, d, d, d, 0_hsize_t], &
                         .true., "1", "fourth-order orientation tensor <p p p p>", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_create(out%file, "a2_family", FOLD_H5_REAL, [character(len=8) :: "j", "i", "family", T], &
                         [d, d, f, 0_hsize_t], .true., "1", "a2 of each particle family", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_create(out%file, "a4_family", FOLD_H5_REAL, [character(len=8) :: "l", "k", "j", "i", "family", T], &
                         [d, d, d, d, f, 0_hsize_t], .true., "1", "a4 of each particle family", stat, errmsg)
      if (stat /= FOLD_OK) return
      call series("n_corrections", FOLD_H5_INT, "1", "contact velocity corrections applied since the previous record")
      if (stat /= FOLD_OK) return
      call series("contact_iterations", FOLD_H5_INT, "1", "largest number of contact-loop iterations in one step")
      if (stat /= FOLD_OK) return
      call series("pairs_left", FOLD_H5_INT, "1", "largest number of pairs left closer than alpha after the contact loop")
      if (stat /= FOLD_OK) return
      call series("capped_steps", FOLD_H5_INT, "1", "steps whose contact loop reached contact_max_iter")
      if (stat /= FOLD_OK) return
      call series("min_gap", FOLD_H5_REAL, "m", "smallest surface gap (particle-particle or particle-wall) after a step; < 0: overlap")
      if (stat /= FOLD_OK) return
      call series("min_gap_over_alpha", FOLD_H5_REAL, "1", "smallest surface gap divided by the security zone alpha")
      if (stat /= FOLD_OK) return
      call series("length_drift", FOLD_H5_REAL, "1", "largest relative change of a fibre's end-to-end length")
      if (stat /= FOLD_OK) return
      call series("unit_norm_drift", FOLD_H5_REAL, "1", "largest deviation of |p| from 1")
      if (stat /= FOLD_OK) return

      if (out%stokes) then
         call series("stokes_iterations", FOLD_H5_INT, "1", &
                     "largest number of Stokes CG iterations of a solve since the previous record")
         if (stat /= FOLD_OK) return
         call series("stokes_residual", FOLD_H5_REAL, "1", &
                     "largest relative preconditioned CG residual reached since the previous record")
         if (stat /= FOLD_OK) return
         call series("rigidity_max", FOLD_H5_REAL, "1", "largest rigidity residual of a particle since the previous "// &
                     "record (non-rigid part of the velocity over a particle / (|E| max(L/2, R)))")
         if (stat /= FOLD_OK) return
         call series("rigidity_mean", FOLD_H5_REAL, "1", &
                     "particle-averaged rigidity residual, largest since the previous record")
         if (stat /= FOLD_OK) return
         call h5_var_create(out%file, "stress", FOLD_H5_REAL, [character(len=8) :: "j", "i", T], [d, d, 0_hsize_t], &
                            .true., "Pa", "deviatoric bulk stress <2 eta eps(u)> of the configuration at the record time", &
                            stat, errmsg)
         if (stat /= FOLD_OK) return
         call series("effective_viscosity", FOLD_H5_REAL, "Pa s", &
                     "effective viscosity Sigma:E/(2 E:E) (= Sigma_xy/shear rate in simple shear) at the record time")
         if (stat /= FOLD_OK) return
      end if

      call h5_var_create(out%file, "snapshot_time", FOLD_H5_REAL, [character(len=8) :: "snapshot"], [0_hsize_t], .true., "s", &
                         "time of the snapshot", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_create(out%file, "x", FOLD_H5_REAL, [character(len=8) :: "xyz", "particle", "snapshot"], [d, n, 0_hsize_t], &
                         .true., "m", "particle centres (primary cell)", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_var_create(out%file, "p", FOLD_H5_REAL, [character(len=8) :: "xyz", "particle", "snapshot"], [d, n, 0_hsize_t], &
                         .true., "1", "particle unit axes", stat, errmsg)
   contains
      subroutine series(name, kind, units, long_name)
         character(len=*), intent(in) :: name, units, long_name
         integer, intent(in) :: kind
         call h5_var_create(out%file, name, kind, [character(len=8) :: T], [0_hsize_t], .true., units, long_name, stat, errmsg)
      end subroutine series
   end subroutine layout

end module fold_output
