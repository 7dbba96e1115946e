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
!> Stokes runs with sphere lubrication (output_open(..., lubrication=.true.)) add
!>   `lubricated_pairs(time)` and `lubrication_correction(time)` [m/s] (largest over the
!>   interval: pairs closer than h_c, largest |delta v| of fold_lubrication).
!> `/checkpoint`: latest full state (`step`, `time`, `x`, `p`, `v`, `omega`; Stokes
!>   runs: the Adams-Bashforth history `v_hydro_prev`, `omega_hydro_prev`) and its
!>   `checksum` (checkpoint_checksum) for `fold_run --resume`; `/checkpoint_shadow`: a
!>   second copy, written (and flushed) before `/checkpoint`, so that a kill leaves one
!>   complete copy (output_checkpoint); a resume verifies the checksums and takes the
!>   newest complete copy.
!> Root attributes written here: `mpi_ranks`, `fortran_creator`, `status`
!>   ("running", "ok" or "failed: step ..., t = ...: cause"), `steps_done`, the
!>   outcome attributes of fold_outcome (`outcome`, `outcome_step`, `outcome_time`,
!>   `outcome_cause`, `outcome_residual`: the same as data), and
!>   `records_complete` / `snapshots_complete`: entries along `time` / `snapshot`
!>   whole on disk (set after the entry's datasets are appended and flushed; a kill
!>   can leave the datasets one longer, or their last entry unwritten: readers and
!>   a resume use only the first `records_complete` / `snapshots_complete`).
!> Every result variable and dimension scale is chunked with HDF5's Fletcher32 checksum
!>   filter (fold_h5 create_extendible); output_resume reads them all back first, so a
!>   damaged record refuses the resume naming it (see docs/scenes.md#checksums).
!> Only one process (MPI rank 0) may hold a run_output_t open (the other ranks only
!>   read /setup and /initial, before it is opened).
module fold_output
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_IO_ERROR
   use fold_outcome, only: outcome_t, outcome_in_progress, outcome_write
   use fold_version, only: fold_version_string, fold_git_revision
   use fold_particles, only: particle_set_t
   use, intrinsic :: iso_fortran_env, only: error_unit
   use fold_h5, only: hid_t, hsize_t, FOLD_H5_REAL, FOLD_H5_INT, h5_open_file, h5_close_file, h5_flush, h5_abandon_file, &
                      h5_put_real_array, h5_put_real_scalar, h5_put_int_scalar, &
                      h5_exists, h5_read_int, h5_read_real, h5_read_int_array, h5_read_real_array, &
                      h5_attr_string, h5_attr_int, h5_read_attr_int, h5_make_group, h5_delete, &
                      h5_scale_int, h5_scale_real, &
                      h5_var_create, h5_var_append_real, h5_var_append_int, h5_var_length, h5_var_truncate, h5_verify
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
      ! ---- Stokes runs with lubrication only (largest over the interval)
      !> Sphere pairs closer than the lubrication threshold h_c in a solve
      integer(i8) :: lubricated_pairs = 0
      !> Largest lubrication correction |delta v| of a sphere [m/s]
      real(dp) :: lubrication_correction = 0.0_dp
   end type run_record_t

   !> An open run file receiving results.
   type, public :: run_output_t
      integer(hid_t) :: file = -1
      integer(ip) :: dim = 3, n = 0, n_families = 1
      !> Records / snapshots written so far
      integer(hsize_t) :: n_records = 0, n_snapshots = 0
      !> Stokes hydrodynamics: solver and stress records are written
      logical :: stokes = .false.
      !> Sphere lubrication (Stokes runs): its records are written
      logical :: lubrication = .false.
   end type run_output_t

   public :: output_open, output_resume, output_record, output_snapshot, output_checkpoint, output_status, &
             output_close, output_abandon, output_failed_status, record_init, checkpoint_checksum

   character(len=*), parameter :: SCALAR_VARS(9) = [character(len=24) :: "step", "n_corrections", &
      "contact_iterations", "pairs_left", "capped_steps", "min_gap", "min_gap_over_alpha", &
      "length_drift", "unit_norm_drift"]
   !> Time series of Stokes runs only (besides `stress`)
   character(len=*), parameter :: STOKES_VARS(5) = [character(len=24) :: "stokes_iterations", "stokes_residual", &
      "rigidity_max", "rigidity_mean", "effective_viscosity"]
   !> Time series of Stokes runs with lubrication only
   character(len=*), parameter :: LUBRICATION_VARS(2) = [character(len=24) :: "lubricated_pairs", &
      "lubrication_correction"]
   !> Dimension scales of fixed length
   character(len=*), parameter :: SCALES(7) = [character(len=24) :: "i", "j", "k", "l", "xyz", "family", "particle"]
   !> Variables over `snapshot`
   character(len=*), parameter :: SNAPSHOT_VARS(4) = [character(len=24) :: "snapshot", "snapshot_time", "x", "p"]
   !> Root attributes: number of records / snapshots completely written (set after the
   !> record's datasets are appended and flushed; readers use no more than these)
   character(len=*), parameter :: RECORDS_COMPLETE = "records_complete", SNAPSHOTS_COMPLETE = "snapshots_complete"
   !> The checkpoint, and its shadow copy (written first)
   character(len=*), parameter :: CKPT = "/checkpoint", CKPT_SHADOW = "/checkpoint_shadow"
   character(len=*), parameter :: CHECKSUM_LONG_NAME = "Fletcher checksum (modulo 4294967291, s2*2**32 + s1) of "// &
      "the 32-bit halves (low first) of the 64-bit words step, time, dim, n, has_prev, x, p, v, omega"// &
      "[, v_hydro_prev, omega_hydro_prev] (Fortran order), s1 = 1, s2 = 0 at the start"

   !> A checkpoint group as read back for a resume.
   type :: checkpoint_t
      character(len=32) :: name = ""
      !> The group exists / is complete and verified / carries a checksum / an AB2 history
      logical :: present = .false., valid = .false., has_checksum = .false., has_prev = .false.
      integer(i8) :: step = 0
      real(dp) :: time = 0.0_dp
      real(dp), allocatable :: x(:, :), p(:, :), v(:, :), omega(:, :), v_prev(:, :), omega_prev(:, :)
      !> Why it is not valid
      character(len=msg_len) :: why = ""
   end type checkpoint_t

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
   subroutine output_open(out, path, parts, n_families, mpi_ranks, stat, errmsg, stokes, lubrication)
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
      !> Stokes run with lubrication: also its records (default .false.)
      logical, intent(in), optional :: lubrication

      call h5_open_file(path, .true., out%file, stat, errmsg); if (stat /= FOLD_OK) return
      out%dim = parts%dim
      out%n = parts%n
      out%n_families = n_families
      if (present(stokes)) out%stokes = stokes
      if (present(lubrication)) out%lubrication = lubrication .and. out%stokes
      if (h5_exists(out%file, "time")) then
         stat = FOLD_INPUT_ERROR
         errmsg = trim(path)//": /time exists, the file already holds results (run with --resume to continue)"
         return
      end if
      call layout(out, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_int(out%file, RECORDS_COMPLETE, 0_i8, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_int(out%file, SNAPSHOTS_COMPLETE, 0_i8, stat, errmsg); if (stat /= FOLD_OK) return
      call run_attributes(out, mpi_ranks, stat, errmsg)
   end subroutine output_open

   !> Reopen a run file at its newest complete checkpoint: returns the checkpoint state
   !> and step, and drops records and snapshots written after that step (and any record
   !> or snapshot beyond `records_complete` / `snapshots_complete`, i.e. torn by a kill).
   !>
   !> The candidates are the two copies `/checkpoint` and `/checkpoint_shadow` (see
   !> output_checkpoint); each must have all its datasets, the expected shapes and a
   !> `checksum` that matches its content. The complete one with the larger step is
   !> used, and a torn or older copy is rewritten from it before the run goes on; when
   !> neither is complete the resume is refused (FOLD_INPUT_ERROR, exit 2) with the
   !> cause of each. A `/checkpoint` without `checksum` and without a shadow (written by
   !> a fold_run of before the checksum: not verifiable) is used with a warning on stderr.
   !> Every result variable is then read whole (h5_verify): a chunk failing its Fletcher32
   !> checksum refuses the resume (FOLD_INPUT_ERROR) naming the variable.
   subroutine output_resume(out, path, parts, n_families, mpi_ranks, step, time, stat, errmsg, stokes, &
                            v_prev, omega_prev, have_prev, lubrication)
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
      !> Stokes run with lubrication: its records are truncated too (default .false.)
      logical, intent(in), optional :: lubrication
      type(checkpoint_t), target :: main, shadow
      type(checkpoint_t), pointer :: pick
      integer(hsize_t) :: keep
      logical :: there

      step = 0
      time = 0.0_dp
      if (present(have_prev)) have_prev = .false.
      call h5_open_file(path, .true., out%file, stat, errmsg)
      if (stat /= FOLD_OK) then
         ! An existing file HDF5 cannot open (e.g. damaged by a kill) is refused as input.
         inquire (file=path, exist=there)
         if (there) then
            stat = FOLD_INPUT_ERROR
            errmsg = trim(errmsg)//" (damaged?): cannot resume from it"
         end if
         return
      end if
      out%dim = parts%dim
      out%n = parts%n
      out%n_families = n_families
      if (present(stokes)) out%stokes = stokes
      if (present(lubrication)) out%lubrication = lubrication .and. out%stokes

      call read_checkpoint(out, CKPT_SHADOW, shadow)
      call read_checkpoint(out, CKPT, main, legacy_ok=.not. shadow%present)
      if (.not. main%present .and. .not. shadow%present) then
         stat = FOLD_INPUT_ERROR
         errmsg = CKPT//"/step: missing, nothing to resume from (stopped before its first checkpoint was "// &
                  "written, or checkpoint_every = 0)"
         return
      end if
      nullify (pick)
      if (main%valid .and. shadow%valid) then
         pick => main
         if (shadow%step > main%step) pick => shadow
      else if (main%valid) then
         pick => main
      else if (shadow%valid) then
         pick => shadow
      end if
      if (.not. associated(pick)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "no complete checkpoint to resume from (damaged, e.g. by a kill during a checkpoint write)"
         if (main%present) errmsg = trim(errmsg)//": "//CKPT//": "//trim(main%why)
         if (main%present .and. shadow%present) errmsg = trim(errmsg)//";"
         if (shadow%present .and. .not. main%present) errmsg = trim(errmsg)//":"
         if (shadow%present) errmsg = trim(errmsg)//" "//CKPT_SHADOW//": "//trim(shadow%why)
         return
      end if
      if (.not. pick%has_checksum) write (error_unit, '(a)') "fold_run: warning: "//CKPT// &
         " has no checksum (written by an older fold_run), resuming from it unverified"

      ! Both copies must hold this checkpoint before the run goes on (the next
      ! checkpoint overwrites the shadow first): rewrite the other copy, then this one
      ! if it lacks a checksum.
      if (associated(pick, main)) then
         call repair(shadow, CKPT_SHADOW); if (stat /= FOLD_OK) return
         call repair(main, CKPT); if (stat /= FOLD_OK) return
      else
         call repair(main, CKPT); if (stat /= FOLD_OK) return
      end if

      step = pick%step
      time = pick%time
      parts%x = pick%x
      parts%p = pick%p
      parts%v = pick%v
      parts%omega = pick%omega
      if (present(v_prev) .and. present(omega_prev) .and. present(have_prev)) then
         if (pick%has_prev) then
            v_prev = pick%v_prev
            omega_prev = pick%omega_prev
            have_prev = .true.
         end if
      end if

      ! Every result variable is read whole first: a chunk that fails its Fletcher32
      ! checksum (a damaged record before the checkpoint) refuses the resume, naming it.
      call verify_results(); if (stat /= FOLD_OK) return
      ! Records are in step order: keep the complete ones up to the checkpoint.
      call keep_upto(record_vars(out), "step", RECORDS_COMPLETE, keep, stat, errmsg); if (stat /= FOLD_OK) return
      out%n_records = keep
      call keep_upto(SNAPSHOT_VARS, "snapshot", SNAPSHOTS_COMPLETE, keep, stat, errmsg); if (stat /= FOLD_OK) return
      out%n_snapshots = keep
      call run_attributes(out, mpi_ranks, stat, errmsg)

   contains

      !> h5_verify of every result variable and dimension scale present.
      subroutine verify_results()
         call verify_list(record_vars(out)); if (stat /= FOLD_OK) return
         call verify_list(SNAPSHOT_VARS); if (stat /= FOLD_OK) return
         call verify_list(SCALES)
      end subroutine verify_results

      subroutine verify_list(names)
         character(len=*), intent(in) :: names(:)
         integer :: k
         do k = 1, size(names)
            if (.not. h5_exists(out%file, trim(names(k)))) cycle
            call h5_verify(out%file, trim(names(k)), stat, errmsg)
            if (stat /= FOLD_OK) then
               errmsg = "/"//trim(errmsg)//"; cannot resume from it"
               return
            end if
         end do
      end subroutine verify_list

      !> Rewrite the copy `name` from the chosen checkpoint unless it holds it already.
      subroutine repair(copy, name)
         type(checkpoint_t), intent(in) :: copy
         character(len=*), intent(in) :: name
         if (copy%valid .and. copy%has_checksum .and. copy%step == pick%step) return
         if (pick%has_prev) then
            call write_copy(out, name, pick%step, pick%time, pick%x, pick%p, pick%v, pick%omega, stat, errmsg, &
                            pick%v_prev, pick%omega_prev)
         else
            call write_copy(out, name, pick%step, pick%time, pick%x, pick%p, pick%v, pick%omega, stat, errmsg)
         end if
         if (stat == FOLD_OK) call h5_flush(out%file, stat, errmsg)
      end subroutine repair

      !> Truncate the variables `vars` (whose step numbers are in `steps_var`) to the
      !> complete entries with step <= the checkpoint step; the count attribute is
      !> lowered first, so a kill in between never exposes an entry as complete.
      subroutine keep_upto(vars, steps_var, count_attr, keep, stat, errmsg)
         character(len=*), intent(in) :: vars(:), steps_var, count_attr
         integer(hsize_t), intent(out) :: keep
         integer, intent(out) :: stat
         character(len=msg_len), intent(out) :: errmsg
         integer(hsize_t) :: ncomplete
         integer(i8), allocatable :: steps(:)
         integer :: k

         keep = 0
         call complete_length(out%file, vars, count_attr, ncomplete, stat, errmsg); if (stat /= FOLD_OK) return
         if (ncomplete > 0) then
            call read_prefix_int(out%file, steps_var, ncomplete, steps, stat, errmsg); if (stat /= FOLD_OK) return
            keep = count(steps(1:ncomplete) <= step)
         end if
         call h5_attr_int(out%file, count_attr, int(keep, i8), stat, errmsg); if (stat /= FOLD_OK) return
         call h5_flush(out%file, stat, errmsg); if (stat /= FOLD_OK) return
         do k = 1, size(vars)
            call h5_var_truncate(out%file, trim(vars(k)), keep, stat, errmsg); if (stat /= FOLD_OK) return
         end do
         call h5_flush(out%file, stat, errmsg)
      end subroutine keep_upto
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
      if (out%lubrication) then
         call h5_var_append_int(out%file, "lubricated_pairs", r, [rec%lubricated_pairs], stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_var_append_real(out%file, "lubrication_correction", r, [rec%lubrication_correction], stat, errmsg)
         if (stat /= FOLD_OK) return
      end if
      ! The record is complete on disk before the count says so.
      call mark_complete(out%file, RECORDS_COMPLETE, r, out%n_records, stat, errmsg)
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
      call mark_complete(out%file, SNAPSHOTS_COMPLETE, r, out%n_snapshots, stat, errmsg)
   end subroutine output_snapshot

   !> Row r of a time axis is complete on disk (flushed) before its count attribute
   !> says so; count <- r, then the attribute is flushed too.
   subroutine mark_complete(file, count_attr, r, count, stat, errmsg)
      integer(hid_t), intent(in) :: file
      character(len=*), intent(in) :: count_attr
      integer(hsize_t), intent(in) :: r
      integer(hsize_t), intent(inout) :: count
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_flush(file, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_int(file, count_attr, int(r, i8), stat, errmsg); if (stat /= FOLD_OK) return
      count = r
      call h5_flush(file, stat, errmsg)
   end subroutine mark_complete

   !> Write the checkpoint, so that a kill at any moment leaves a complete one: the state
   !> is written into `/checkpoint_shadow`, the file flushed, then into `/checkpoint`,
   !> and flushed again. A kill during the first write leaves `/checkpoint` complete
   !> (the previous checkpoint), during the second the shadow (this one); the torn copy
   !> fails its `checksum` on resume. Each copy's datasets are overwritten in place
   !> (raw data only): after the first checkpoint no group or link changes, which a
   !> kill could leave half-written in the file's metadata.
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
      character(len=*), parameter :: COPIES(2) = [character(len=24) :: CKPT_SHADOW, CKPT]
      integer :: k

      do k = 1, 2
         if (present(v_prev) .and. present(omega_prev)) then
            call write_copy(out, trim(COPIES(k)), step, time, parts%x, parts%p, parts%v, parts%omega, stat, errmsg, &
                            v_prev, omega_prev)
         else
            call write_copy(out, trim(COPIES(k)), step, time, parts%x, parts%p, parts%v, parts%omega, stat, errmsg)
         end if
         if (stat /= FOLD_OK) return
         call h5_flush(out%file, stat, errmsg); if (stat /= FOLD_OK) return
      end do
   end subroutine output_checkpoint

   !> Set the root attributes `status`, `steps_done` and the outcome (fold_outcome)
   !> and flush.
   subroutine output_status(out, status, steps_done, stat, errmsg, outcome)
      type(run_output_t), intent(inout) :: out
      character(len=*), intent(in) :: status
      integer(i8), intent(in) :: steps_done
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> How the run ended (the same as `status`, as data)
      type(outcome_t), intent(in), optional :: outcome
      call h5_attr_string(out%file, "status", status, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_int(out%file, "steps_done", steps_done, stat, errmsg); if (stat /= FOLD_OK) return
      if (present(outcome)) then
         call outcome_write(out%file, outcome, stat, errmsg); if (stat /= FOLD_OK) return
      end if
      call h5_flush(out%file, stat, errmsg)
   end subroutine output_status

   !> After a write failure: close the file without writing more into it
   !> (output_abandon), then reopen it and set `status` and `steps_done` alone (the
   !> reopened file has nothing else to flush: two small attribute messages in the
   !> root's object header, the text in the global heap, where the previous status
   !> left room) and close it. Best effort: on a full disk this can fail too (stat,
   !> errmsg say why; a failed flush is followed by output_abandon again). The
   !> outcome attributes follow in a second flush, so that a file with room for the
   !> status alone still gets it (readers then see the outcome "running" beside a
   !> failed status, and read the status).
   subroutine output_failed_status(out, path, status, steps_done, stat, errmsg, outcome)
      type(run_output_t), intent(inout) :: out
      character(len=*), intent(in) :: path, status
      integer(i8), intent(in) :: steps_done
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> How the run ended (the same as `status`, as data)
      type(outcome_t), intent(in), optional :: outcome
      integer :: s2
      character(len=msg_len) :: m2
      call output_abandon(out, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_open_file(path, .true., out%file, stat, errmsg); if (stat /= FOLD_OK) return
      call output_status(out, status, steps_done, stat, errmsg)
      if (stat == FOLD_OK .and. present(outcome)) then
         call outcome_write(out%file, outcome, s2, m2)
         if (s2 == FOLD_OK) call h5_flush(out%file, s2, m2)
      end if
      if (stat /= FOLD_OK) then
         call output_abandon(out, s2, m2)
         if (s2 /= FOLD_OK) errmsg = trim(errmsg)//"; "//trim(m2)
         return
      end if
      call output_close(out, stat, errmsg)
   end subroutine output_failed_status

   !> Close the file.
   subroutine output_close(out, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_close_file(out%file, stat, errmsg)
   end subroutine output_close

   !> Close a file that refuses writes (full disk) without writing more into it
   !> (h5_abandon_file): it stays as its last successful flush left it.
   subroutine output_abandon(out, stat, errmsg)
      type(run_output_t), intent(inout) :: out
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_abandon_file(out%file, stat, errmsg)
   end subroutine output_abandon

   ! ------------------------------------------------------------------ internals

   !> Checksum of a checkpoint (see CHECKSUM_LONG_NAME): Fletcher sums modulo the prime
   !> 2**32 - 5 over the 32-bit halves of the bit patterns of step, time, the sizes and
   !> every array, in order; any array of another step (a torn write) changes it.
   function checkpoint_checksum(step, time, x, p, v, omega, v_prev, omega_prev) result(sum)
      integer(i8), intent(in) :: step
      real(dp), intent(in) :: time
      real(dp), intent(in) :: x(:, :), p(:, :), v(:, :), omega(:, :)
      real(dp), intent(in), optional :: v_prev(:, :), omega_prev(:, :)
      integer(i8) :: sum
      integer(i8) :: s1, s2, has_prev

      s1 = 1
      s2 = 0
      has_prev = merge(1_i8, 0_i8, present(v_prev) .and. present(omega_prev))
      call fletcher([step, transfer(time, 0_i8), int(size(x, 1), i8), int(size(x, 2), i8), has_prev])
      call fletcher(transfer(x, [0_i8]))
      call fletcher(transfer(p, [0_i8]))
      call fletcher(transfer(v, [0_i8]))
      call fletcher(transfer(omega, [0_i8]))
      if (has_prev == 1) then
         call fletcher(transfer(v_prev, [0_i8]))
         call fletcher(transfer(omega_prev, [0_i8]))
      end if
      sum = ior(ishft(s2, 32), s1)
   contains
      subroutine fletcher(words)
         integer(i8), intent(in) :: words(:)
         integer(i8), parameter :: PRIME = 4294967291_i8, LOW = 4294967295_i8
         integer :: k
         do k = 1, size(words)
            s1 = mod(s1 + iand(words(k), LOW), PRIME)
            s2 = mod(s2 + s1, PRIME)
            s1 = mod(s1 + iand(ishft(words(k), -32), LOW), PRIME)
            s2 = mod(s2 + s1, PRIME)
         end do
      end subroutine fletcher
   end function checkpoint_checksum

   !> Write one copy of a checkpoint into the group `g` (arrays, time, step, checksum
   !> last), in place where its datasets exist.
   subroutine write_copy(out, g, step, time, x, p, v, omega, stat, errmsg, v_prev, omega_prev)
      type(run_output_t), intent(in) :: out
      character(len=*), intent(in) :: g
      integer(i8), intent(in) :: step
      real(dp), intent(in) :: time
      real(dp), intent(in) :: x(:, :), p(:, :), v(:, :), omega(:, :)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp), intent(in), optional :: v_prev(:, :), omega_prev(:, :)
      integer(hsize_t) :: d, n
      integer(i8) :: sum

      d = int(size(x, 1), hsize_t)
      n = int(size(x, 2), hsize_t)
      call h5_make_group(out%file, g, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_put_real_array(out%file, g//"/x", reshape(x, [size(x)]), [d, n], "m", "particle centres", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_put_real_array(out%file, g//"/p", reshape(p, [size(p)]), [d, n], "1", "particle unit axes", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_put_real_array(out%file, g//"/v", reshape(v, [size(v)]), [d, n], "m s-1", &
                             "particle velocities of the last step", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_put_real_array(out%file, g//"/omega", reshape(omega, [size(omega)]), [3_hsize_t, n], &
                             "s-1", "particle angular velocities of the last step", stat, errmsg)
      if (stat /= FOLD_OK) return
      if (present(v_prev) .and. present(omega_prev)) then
         call h5_put_real_array(out%file, g//"/v_hydro_prev", reshape(v_prev, [size(v_prev)]), [d, n], &
                                "m s-1", "Stokes velocities of the step before the checkpoint (Adams-Bashforth history)", &
                                stat, errmsg)
         if (stat /= FOLD_OK) return
         call h5_put_real_array(out%file, g//"/omega_hydro_prev", reshape(omega_prev, [size(omega_prev)]), &
                                [3_hsize_t, n], "s-1", &
                                "Stokes angular velocities of the step before the checkpoint (Adams-Bashforth history)", &
                                stat, errmsg)
         if (stat /= FOLD_OK) return
         sum = checkpoint_checksum(step, time, x, p, v, omega, v_prev, omega_prev)
      else
         ! (only a checkpoint before the first Stokes step has no history)
         call h5_delete(out%file, g//"/v_hydro_prev", stat, errmsg); if (stat /= FOLD_OK) return
         call h5_delete(out%file, g//"/omega_hydro_prev", stat, errmsg); if (stat /= FOLD_OK) return
         sum = checkpoint_checksum(step, time, x, p, v, omega)
      end if
      call h5_put_real_scalar(out%file, g//"/time", time, "s", "time of the checkpoint", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_put_int_scalar(out%file, g//"/step", step, "step number of the checkpoint", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5_put_int_scalar(out%file, g//"/checksum", sum, CHECKSUM_LONG_NAME, stat, errmsg)
   end subroutine write_copy

   !> Read and verify the checkpoint group `name` (for output_resume).
   subroutine read_checkpoint(out, name, ck, legacy_ok)
      type(run_output_t), intent(in) :: out
      character(len=*), intent(in) :: name
      type(checkpoint_t), intent(out) :: ck
      !> A copy without checksum (fold_run of before the checksum) counts as complete
      logical, intent(in), optional :: legacy_ok
      real(dp), allocatable :: buf(:)
      integer(hsize_t) :: d, n
      integer(i8) :: stored, sum
      integer :: stat
      character(len=msg_len) :: errmsg
      logical :: hv, ho

      ck%name = name
      ck%present = h5_exists(out%file, name)
      if (.not. ck%present) return
      d = int(out%dim, hsize_t)
      n = int(out%n, hsize_t)
      if (.not. h5_exists(out%file, name//"/step")) then
         ck%why = "step missing (incomplete write)"
         return
      end if
      call h5_read_int(out%file, name//"/step", ck%step, stat, errmsg); if (stat /= FOLD_OK) goto 9
      call h5_read_real(out%file, name//"/time", ck%time, stat, errmsg); if (stat /= FOLD_OK) goto 9
      call h5_read_real_array(out%file, name//"/x", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) goto 9
      ck%x = reshape(buf, [out%dim, out%n])
      call h5_read_real_array(out%file, name//"/p", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) goto 9
      ck%p = reshape(buf, [out%dim, out%n])
      call h5_read_real_array(out%file, name//"/v", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) goto 9
      ck%v = reshape(buf, [out%dim, out%n])
      call h5_read_real_array(out%file, name//"/omega", [3_hsize_t, n], buf, stat, errmsg); if (stat /= FOLD_OK) goto 9
      ck%omega = reshape(buf, [3, out%n])
      hv = h5_exists(out%file, name//"/v_hydro_prev")
      ho = h5_exists(out%file, name//"/omega_hydro_prev")
      if (hv .neqv. ho) then
         ck%why = "only one of v_hydro_prev, omega_hydro_prev present (incomplete write)"
         return
      end if
      ck%has_prev = hv
      if (ck%has_prev) then
         call h5_read_real_array(out%file, name//"/v_hydro_prev", [d, n], buf, stat, errmsg); if (stat /= FOLD_OK) goto 9
         ck%v_prev = reshape(buf, [out%dim, out%n])
         call h5_read_real_array(out%file, name//"/omega_hydro_prev", [3_hsize_t, n], buf, stat, errmsg)
         if (stat /= FOLD_OK) goto 9
         ck%omega_prev = reshape(buf, [3, out%n])
      end if
      ck%has_checksum = h5_exists(out%file, name//"/checksum")
      if (.not. ck%has_checksum) then
         ! Only the fold_run of before the checksum wrote /checkpoint without one
         ! (and no shadow).
         ck%valid = .false.
         if (present(legacy_ok)) ck%valid = legacy_ok
         if (.not. ck%valid) ck%why = "checksum missing (incomplete write)"
         return
      end if
      call h5_read_int(out%file, name//"/checksum", stored, stat, errmsg); if (stat /= FOLD_OK) goto 9
      if (ck%has_prev) then
         sum = checkpoint_checksum(ck%step, ck%time, ck%x, ck%p, ck%v, ck%omega, ck%v_prev, ck%omega_prev)
      else
         sum = checkpoint_checksum(ck%step, ck%time, ck%x, ck%p, ck%v, ck%omega)
      end if
      if (sum /= stored) then
         write (ck%why, '(a,i0,a)') "checksum mismatch at step ", ck%step, &
            " (its arrays are not all of that step: torn write)"
         return
      end if
      ck%valid = .true.
      return
9     ck%why = errmsg
   end subroutine read_checkpoint

   !> Names of the variables over `time` of this run.
   function record_vars(out) result(names)
      type(run_output_t), intent(in) :: out
      character(len=24), allocatable :: names(:)
      names = [character(len=24) :: "time", SCALAR_VARS, "a2", "a4", "a2_family", "a4_family"]
      if (out%stokes) names = [character(len=24) :: names, STOKES_VARS, "stress"]
      if (out%lubrication) names = [character(len=24) :: names, LUBRICATION_VARS]
   end function record_vars

   !> Number of complete entries of the variables `vars`: the count attribute when
   !> present (never more than the shortest variable), else the shortest variable
   !> (files of a fold_run without the count).
   subroutine complete_length(file, vars, count_attr, length, stat, errmsg)
      integer(hid_t), intent(in) :: file
      character(len=*), intent(in) :: vars(:), count_attr
      integer(hsize_t), intent(out) :: length
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hsize_t) :: nk
      integer(i8) :: counted
      logical :: found
      integer :: k

      length = huge(length)
      do k = 1, size(vars)
         call h5_var_length(file, trim(vars(k)), nk, stat, errmsg); if (stat /= FOLD_OK) return
         length = min(length, nk)
      end do
      if (size(vars) == 0) length = 0
      call h5_read_attr_int(file, count_attr, counted, found, stat, errmsg); if (stat /= FOLD_OK) return
      if (found) length = min(length, int(max(counted, 0_i8), hsize_t))
   end subroutine complete_length

   !> The first `n` values of a 1-D integer variable.
   subroutine read_prefix_int(file, name, n, values, stat, errmsg)
      integer(hid_t), intent(in) :: file
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: n
      integer(i8), allocatable, intent(out) :: values(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hsize_t) :: length
      integer(i8), allocatable :: all(:)
      call h5_var_length(file, name, length, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_read_int_array(file, name, [length], all, stat, errmsg); if (stat /= FOLD_OK) return
      values = all(1:n)
   end subroutine read_prefix_int


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
      call outcome_write(out%file, outcome_in_progress(), stat, errmsg); if (stat /= FOLD_OK) return
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
      call series("contact_iterations", FOLD_H5_INT, "1", "largest number of contact-loop iterations in one step")
      call series("pairs_left", FOLD_H5_INT, "1", "largest number of pairs left closer than alpha after the contact loop")
      call series("capped_steps", FOLD_H5_INT, "1", "steps whose contact loop reached contact_max_iter")
      call series("min_gap", FOLD_H5_REAL, "m", "smallest surface gap (particle-particle or particle-wall) after a step; < 0: overlap")
      call series("min_gap_over_alpha", FOLD_H5_REAL, "1", "smallest surface gap divided by the security zone alpha")
      call series("length_drift", FOLD_H5_REAL, "1", "largest relative change of a fibre's end-to-end length")
      call series("unit_norm_drift", FOLD_H5_REAL, "1", "largest deviation of |p| from 1")
      if (stat /= FOLD_OK) return

      if (out%stokes) then
         call series("stokes_iterations", FOLD_H5_INT, "1", &
                     "largest number of Stokes CG iterations of a solve since the previous record")
         call series("stokes_residual", FOLD_H5_REAL, "1", &
                     "largest relative preconditioned CG residual reached since the previous record")
         call series("rigidity_max", FOLD_H5_REAL, "1", "largest rigidity residual of a particle since the previous "// &
                     "record (non-rigid part of the velocity over a particle / (|E| max(L/2, R)))")
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
      if (out%lubrication) then
         call series("lubricated_pairs", FOLD_H5_INT, "1", "largest number of sphere pairs closer than the "// &
                     "lubrication threshold h_c (2 voxels) in a solve since the previous record")
         call series("lubrication_correction", FOLD_H5_REAL, "m/s", "largest lubrication velocity correction "// &
                     "|delta v| of a sphere since the previous record")
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
         if (stat /= FOLD_OK) return  ! after a failure: a run of calls needs one check after it
         call h5_var_create(out%file, name, kind, [character(len=8) :: T], [0_hsize_t], .true., units, long_name, stat, errmsg)
      end subroutine series
   end subroutine layout

end module fold_output
