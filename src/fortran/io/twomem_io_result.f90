!> The result file of docs/output.md: provenance attributes on `/`, the finest mesh, the nodal
!> solution, per-element errors, the history and a summary, plus the XDMF sidecar for ParaView.
!> The HDF5 file is written under a temporary name in the target directory and renamed when
!> complete, so a reader never sees half a result; a failure removes the temporary file.
module twomem_io_result
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t
   use twomem_base_system, only: rename_file, remove_file, process_id, base_name, register_temporary, &
      unregister_temporary
   use twomem_hdf5_file, only: h5_file_t
   use twomem_io_xdmf, only: write_xdmf, write_xdmf_steps
   use twomem_base_phases, only: phase_clock_t, phase_output, n_phases, phase_names
   implicit none
   private

   public :: result_record_t, history_columns_t, adapt_step_t, output_choice_t, write_result, xdmf_path_for, &
             steps_xdmf_path_for

   !> One step of an adaptive run (`/adapt`): its mesh, solution and element indicators (whole,
   !> as the final ones are stored) and its totals. energy_error is NaN without an exact
   !> solution; wall_time covers the step's solve, estimate, marking and refinement.
   type :: adapt_step_t
      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      real(dp), allocatable :: u1(:), u2(:), lambda(:), eta_disc_k(:)
      real(dp) :: eta = 0, eta_disc = 0, eta_lin = 0, eta_alg = 0, energy_error = 0, wall_time = 0
      integer :: newton_iterations = 0, gmres_iterations = 0
   end type adapt_step_t

   !> `/history` column by column, one entry per recorded point (docs/output.md). The program
   !> copies the solver's rows in: the file's layout is fixed here, the solver's types stay above.
   type :: history_columns_t
      integer(ip), allocatable :: newton_it(:), gmres_it(:), active(:), active_changed(:)
      !> 1 for a point recorded inside GMRES, 0 for a Newton step
      integer(ip), allocatable :: inner(:)
      real(dp), allocatable :: eta_disc(:), eta_lin(:), eta_alg(:), eta_total(:), energy_error(:)
      real(dp), allocatable :: lin_residual(:), alg_residual(:), step(:), wall_time(:)
   end type history_columns_t

   !> What the run produced, independent of how it is stored.
   type :: result_record_t
      character(len=:), allocatable :: version, input_text, status
      !> the UMFPACK and BLAS the run solved with (twomem_linalg_umfpack's umfpack_library)
      character(len=:), allocatable :: umfpack
      !> the finest mesh, whole: vertices (2, nv), triangles (3, nt)
      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      real(dp), allocatable :: u1(:), u2(:), lambda(:)
      !> per-element energy error, allocated only when the exact solution is known
      real(dp), allocatable :: energy_error(:)
      type(history_columns_t) :: history
      integer :: newton_iterations = 0, gmres_iterations = 0, levels = 0
      !> work on the coarser levels of nested iteration (0 without it)
      integer :: newton_iterations_coarse = 0, gmres_iterations_coarse = 0
      real(dp) :: eta_total = 0.0_dp, energy_error_total = 0.0_dp, effectivity = 0.0_dp
      !> the components of the final estimate (Cor. 5.6 of the paper)
      real(dp) :: eta_disc = 0.0_dp, eta_lin = 0.0_dp, eta_alg = 0.0_dp
      !> the one-level algebraic flux's remainder η_rem, part of eta_alg (0 with the multilevel one)
      real(dp) :: eta_alg_remainder = 0.0_dp
      !> per-element estimators (nt, n_fields) named by estimator_names, with their global values;
      !> allocated only when computed and asked for
      character(len=16), allocatable :: estimator_names(:)
      real(dp), allocatable :: estimators(:, :), estimator_totals(:)
      !> how often the estimators were evaluated and how long that took in total
      integer :: estimator_evaluations = 0
      real(dp) :: estimator_time = 0.0_dp
      real(dp) :: wall_time = 0.0_dp
      integer(i8) :: peak_memory_kib = 0
      integer :: omp_threads = 1, mpi_ranks = 1
      !> the steps of an adaptive run, the last one's mesh and fields being the record's own;
      !> not allocated without adaptation
      type(adapt_step_t), allocatable :: adapt(:)
   end type result_record_t

   !> The output.* switches.
   type :: output_choice_t
      logical :: fields = .true., estimators = .true., history = .true., xdmf = .true.
   end type output_choice_t

contains

   !> `name.h5` → `name.xdmf` (any other extension: appended).
   pure function xdmf_path_for(path) result(xdmf)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: xdmf

      integer :: n

      n = len_trim(path)
      if (n > 3) then
         if (path(n - 2:n) == '.h5') then
            xdmf = path(1:n - 3)//'.xdmf'
            return
         end if
      end if
      xdmf = trim(path)//'.xdmf'
   end function xdmf_path_for

   !> `name.h5` → `name.steps.xdmf`: the temporal collection of an adaptive run's meshes.
   pure function steps_xdmf_path_for(path) result(xdmf)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: xdmf

      xdmf = xdmf_path_for(path)
      xdmf = xdmf(1:len(xdmf) - 5)//'.steps.xdmf'
   end function steps_xdmf_path_for

   !> Write the result atomically. With `clock` (the run's phase clock, in its output phase) the
   !> file ends with the `/performance` group: each phase's time and peak memory up to then.
   subroutine write_result(path, rec, choice, err, clock)
      character(len=*), intent(in) :: path
      type(result_record_t), intent(in) :: rec
      type(output_choice_t), intent(in) :: choice
      type(error_t), allocatable, intent(out) :: err
      type(phase_clock_t), intent(inout), optional :: clock

      type(h5_file_t) :: h5
      type(error_t), allocatable :: cleanup_err
      character(len=:), allocatable :: tmp
      character(len=32) :: pid
      logical :: with_mesh
      character(len=64), allocatable :: cells(:)
      integer :: i

      write (pid, '(i0)') process_id()
      tmp = trim(path)//'.tmp-'//trim(pid)
      ! a SIGTERM or SIGINT from here to the rename removes the temporary (twomem_guard.c)
      call register_temporary(tmp)
      call h5%create(tmp, err)
      if (allocated(err)) then
         call unregister_temporary()
         return
      end if
      with_mesh = choice%fields .or. allocated(rec%energy_error) .or. allocated(rec%estimators)
      call write_contents(h5, rec, choice, with_mesh, err)
      if (.not. allocated(err) .and. present(clock)) call write_performance(h5, clock, err)
      if (allocated(err)) then
         call h5%close(cleanup_err)
         call remove_file(tmp, cleanup_err)
         call unregister_temporary()
         return
      end if
      call h5%close(err)
      if (.not. allocated(err)) call rename_file(tmp, path, err)
      if (allocated(err)) call remove_file(tmp, cleanup_err)
      call unregister_temporary()
      if (allocated(err)) return
      if (choice%xdmf .and. with_mesh) then
         allocate (cells(0))
         if (allocated(rec%energy_error)) cells = [character(len=64) :: '/error/energy']
         if (allocated(rec%estimators)) cells = [character(len=64) :: cells, &
                                                 ('/estimators/'//rec%estimator_names(i), i=1, size(rec%estimator_names))]
         if (choice%fields) then
            call write_xdmf(xdmf_path_for(path), base_name(path), size(rec%vertices, 2, ip), size(rec%triangles, 2, ip), &
                            [character(len=64) :: '/solution/u1', '/solution/u2', '/solution/lambda'], &
                            cells, err)
         else
            call write_xdmf(xdmf_path_for(path), base_name(path), size(rec%vertices, 2, ip), size(rec%triangles, 2, ip), &
                            [character(len=64) ::], cells, err)
         end if
      end if
      if (allocated(err) .or. .not. (choice%xdmf .and. choice%fields .and. allocated(rec%adapt))) return
      call write_xdmf_steps(steps_xdmf_path_for(path), base_name(path), step_groups(size(rec%adapt)), &
                            [(size(rec%adapt(i)%vertices, 2, ip), i=1, size(rec%adapt))], &
                            [(size(rec%adapt(i)%triangles, 2, ip), i=1, size(rec%adapt))], &
                            [character(len=64) :: 'u1', 'u2', 'lambda'], [character(len=64) :: 'eta_disc'], err)
   end subroutine write_result

   !> '/adapt/step_001', ...: where each step's mesh and fields are stored.
   pure function step_groups(n) result(groups)
      integer, intent(in) :: n
      character(len=64) :: groups(n)

      integer :: i

      do i = 1, n
         write (groups(i), '("/adapt/step_",i3.3)') i
      end do
   end function step_groups

   !> `/adapt`: one entry per step in each dataset, and with the fields each step's mesh,
   !> solution and discretization indicators in its own group.
   subroutine write_adapt(h5, steps, fields, err)
      type(h5_file_t), intent(inout) :: h5
      type(adapt_step_t), intent(in) :: steps(:)
      logical, intent(in) :: fields
      type(error_t), allocatable, intent(out) :: err

      character(len=64), allocatable :: groups(:)
      character(len=:), allocatable :: g
      integer :: i

      call h5%write_int('/adapt/vertices', [(size(steps(i)%vertices, 2, ip), i=1, size(steps))], err)
      if (.not. allocated(err)) call h5%write_int('/adapt/triangles', [(size(steps(i)%triangles, 2, ip), &
                                                                        i=1, size(steps))], err)
      if (.not. allocated(err)) call h5%write_real('/adapt/eta', steps%eta, err)
      if (.not. allocated(err)) call h5%write_real('/adapt/eta_disc', steps%eta_disc, err)
      if (.not. allocated(err)) call h5%write_real('/adapt/eta_lin', steps%eta_lin, err)
      if (.not. allocated(err)) call h5%write_real('/adapt/eta_alg', steps%eta_alg, err)
      if (.not. allocated(err)) call h5%write_real('/adapt/energy_error', steps%energy_error, err)
      if (.not. allocated(err)) call h5%write_real('/adapt/wall_time', steps%wall_time, err)
      if (.not. allocated(err)) call h5%write_int('/adapt/newton_iterations', int(steps%newton_iterations, ip), err)
      if (.not. allocated(err)) call h5%write_int('/adapt/gmres_iterations', int(steps%gmres_iterations, ip), err)
      if (allocated(err) .or. .not. fields) return
      groups = step_groups(size(steps))
      do i = 1, size(steps)
         g = trim(groups(i))
         call h5%write_real(g//'/vertices', steps(i)%vertices, err)
         if (.not. allocated(err)) call h5%write_int(g//'/triangles', steps(i)%triangles - 1_ip, err)
         if (.not. allocated(err)) call h5%write_real(g//'/u1', steps(i)%u1, err)
         if (.not. allocated(err)) call h5%write_real(g//'/u2', steps(i)%u2, err)
         if (.not. allocated(err)) call h5%write_real(g//'/lambda', steps(i)%lambda, err)
         if (.not. allocated(err)) call h5%write_real(g//'/eta_disc', steps(i)%eta_disc_k, err)
         if (allocated(err)) return
      end do
   end subroutine write_adapt

   subroutine write_contents(h5, rec, choice, with_mesh, err)
      type(h5_file_t), intent(inout) :: h5
      type(result_record_t), intent(in) :: rec
      type(output_choice_t), intent(in) :: choice
      logical, intent(in) :: with_mesh
      type(error_t), allocatable, intent(out) :: err

      call h5%write_attr('/', 'version', rec%version, err)
      if (.not. allocated(err)) call h5%write_attr('/', 'input', rec%input_text, err)
      if (.not. allocated(err)) call h5%write_attr('/', 'status', rec%status, err)
      if (.not. allocated(err)) call h5%write_attr('/', 'umfpack', rec%umfpack, err)
      if (allocated(err)) return
      if (with_mesh) then
         call h5%write_real('/mesh/vertices', rec%vertices, err)
         if (.not. allocated(err)) call h5%write_int('/mesh/triangles', rec%triangles - 1_ip, err)
         if (allocated(err)) return
      end if
      if (choice%fields) then
         call h5%write_real('/solution/u1', rec%u1, err)
         if (.not. allocated(err)) call h5%write_real('/solution/u2', rec%u2, err)
         if (.not. allocated(err)) call h5%write_real('/solution/lambda', rec%lambda, err)
         if (allocated(err)) return
      end if
      if (allocated(rec%energy_error)) then
         call h5%write_real('/error/energy', rec%energy_error, err)
         if (.not. allocated(err)) call h5%write_attr('/error/energy', 'total', rec%energy_error_total, err)
         if (allocated(err)) return
      end if
      if (allocated(rec%estimators)) then
         call write_estimators(h5, rec, err)
         if (allocated(err)) return
      end if
      if (choice%history) then
         call write_history(h5, rec%history, err)
         if (allocated(err)) return
      end if
      if (allocated(rec%adapt)) then
         call write_adapt(h5, rec%adapt, choice%fields, err)
         if (allocated(err)) return
      end if
      call write_summary(h5, rec, err)
   end subroutine write_contents

   subroutine write_estimators(h5, rec, err)
      type(h5_file_t), intent(inout) :: h5
      type(result_record_t), intent(in) :: rec
      type(error_t), allocatable, intent(out) :: err

      integer :: i
      character(len=:), allocatable :: path

      do i = 1, size(rec%estimator_names)
         path = '/estimators/'//trim(rec%estimator_names(i))
         call h5%write_real(path, rec%estimators(:, i), err)
         if (.not. allocated(err)) call h5%write_attr(path, 'total', rec%estimator_totals(i), err)
         if (allocated(err)) return
      end do
   end subroutine write_estimators

   subroutine write_history(h5, history, err)
      type(h5_file_t), intent(inout) :: h5
      type(history_columns_t), intent(in) :: history
      type(error_t), allocatable, intent(out) :: err

      call h5%write_int('/history/newton_it', history%newton_it, err)
      if (.not. allocated(err)) call h5%write_int('/history/gmres_it', history%gmres_it, err)
      if (.not. allocated(err)) call h5%write_real('/history/eta_disc', history%eta_disc, err)
      if (.not. allocated(err)) call h5%write_real('/history/eta_lin', history%eta_lin, err)
      if (.not. allocated(err)) call h5%write_real('/history/eta_alg', history%eta_alg, err)
      if (.not. allocated(err)) call h5%write_real('/history/eta_total', history%eta_total, err)
      if (.not. allocated(err)) call h5%write_real('/history/energy_error', history%energy_error, err)
      if (.not. allocated(err)) call h5%write_real('/history/lin_residual', history%lin_residual, err)
      if (.not. allocated(err)) call h5%write_real('/history/alg_residual', history%alg_residual, err)
      if (.not. allocated(err)) call h5%write_int('/history/active', history%active, err)
      if (.not. allocated(err)) call h5%write_int('/history/active_changed', history%active_changed, err)
      if (.not. allocated(err)) call h5%write_real('/history/step', history%step, err)
      if (.not. allocated(err)) call h5%write_int('/history/inner', history%inner, err)
      if (.not. allocated(err)) call h5%write_real('/history/wall_time', history%wall_time, err)
   end subroutine write_history

   subroutine write_summary(h5, rec, err)
      type(h5_file_t), intent(inout) :: h5
      type(result_record_t), intent(in) :: rec
      type(error_t), allocatable, intent(out) :: err

      call h5%write_attr('/summary', 'newton_iterations', rec%newton_iterations, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'gmres_iterations', rec%gmres_iterations, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'newton_iterations_coarse', &
                                                   rec%newton_iterations_coarse, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'gmres_iterations_coarse', &
                                                   rec%gmres_iterations_coarse, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'eta_total', rec%eta_total, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'eta_disc', rec%eta_disc, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'eta_lin', rec%eta_lin, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'eta_alg', rec%eta_alg, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'eta_alg_remainder', rec%eta_alg_remainder, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'estimator_evaluations', rec%estimator_evaluations, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'estimator_time', rec%estimator_time, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'energy_error', rec%energy_error_total, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'effectivity', rec%effectivity, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'wall_time', rec%wall_time, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'nv', size(rec%vertices, 2), err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'nt', size(rec%triangles, 2), err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'levels', rec%levels, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'peak_memory_kib', int(rec%peak_memory_kib), err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'omp_threads', rec%omp_threads, err)
      if (.not. allocated(err)) call h5%write_attr('/summary', 'mpi_ranks', rec%mpi_ranks, err)
      if (.not. allocated(err) .and. allocated(rec%adapt)) &
         call h5%write_attr('/summary', 'adapt_steps', size(rec%adapt), err)
   end subroutine write_summary

   !> `/performance`: attributes `<phase>_seconds` and `<phase>_peak_mib` for every phase.
   subroutine write_performance(h5, clock, err)
      type(h5_file_t), intent(inout) :: h5
      type(phase_clock_t), intent(inout) :: clock
      type(error_t), allocatable, intent(out) :: err

      integer :: i

      ! bring the output phase up to date: everything written so far
      call clock%switch(phase_output)
      do i = 1, n_phases
         call h5%write_attr('/performance', trim(phase_names(i))//'_seconds', clock%seconds(i), err)
         if (.not. allocated(err)) call h5%write_attr('/performance', trim(phase_names(i))//'_peak_mib', &
                                                      real(clock%peak_kib(i), dp)/1024, err)
         if (allocated(err)) return
      end do
   end subroutine write_performance
end module twomem_io_result
