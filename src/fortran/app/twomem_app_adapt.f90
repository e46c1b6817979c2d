!> Adaptive refinement, SOLVE → ESTIMATE → MARK → REFINE, until the guaranteed bound η meets
!> adapt.tol: each step solves on its mesh with the configured method (`twomem_app_solve`),
!> marks the triangles carrying θ of Σ η_disc,K² (`twomem_mesh_marking`), bisects them with the
!> conforming closure (`twomem_mesh_bisection`) and starts the next solve from the solution
!> interpolated to the finer mesh, which is nested in the coarser one. Every refined mesh is
!> solved on as a single mesh: multigrid takes algebraic coarse levels and the estimators their
!> generic patches and one-level algebraic flux, whose costs per vertex do not depend on how
!> the mesh was made. The first step is a plain run on the configured mesh (its nested start
!> included), whose finest level the refinement starts from with longest edges as refinement
!> edges. Each later solve's first estimator check is told the previous η_disc scaled by the
!> optimal rate, (N_old/N_new)^½, which the new one follows to within a few percent: the check
!> then skips the discretization flux while η_lin is clearly too large for Newton to stop.
!> The loop stops at η ≤ tol, or at adapt.max_steps solves, or before a mesh would exceed
!> adapt.max_vertices; the last step solved is the result. A distributed run keeps the
!> mesh, not the matrices, replicated between solves: every rank marks and bisects the whole
!> mesh identically (both are deterministic) from rank 0's gathered solution and indicators,
!> and METIS partitions each new mesh as a user's mesh is partitioned at start-up.
module twomem_app_adapt
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_is_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_timer, only: wall_time
   use twomem_base_text, only: fixed, int_text
   use twomem_base_phases, only: phase_clock_t, phase_mesh, phase_assembly
   use twomem_base_comm, only: comm_t
   use twomem_input_config, only: config_t
   use twomem_input_values, only: format_real
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t, refinement_map_t
   use twomem_mesh_bisection, only: longest_edge_first, bisect_marked
   use twomem_mesh_partition, only: share_mesh, distribute_coarse
   use twomem_mesh_marking, only: dorfler_marking
   use twomem_fem_problem, only: problem_data_t
   use twomem_app_solve, only: solve_mesh
   use twomem_io_result, only: result_record_t, adapt_step_t
   implicit none
   private

   public :: adapt_mesh

contains

   !> Refine `hierarchy`'s finest mesh adaptively; `rec` is the last step's result with every
   !> step in rec%adapt (rank 0). `converged`: η ≤ tol was reached and the last solve converged.
   !> Collective: every rank holds the whole current mesh, the gathered solution and indicators
   !> (broadcast from rank 0), marks and bisects identically, and solves on its METIS piece of
   !> the new mesh.
   subroutine adapt_mesh(cfg, comm, hierarchy, data, clock, rec, converged, exit_code, err)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), target, intent(in) :: hierarchy
      class(problem_data_t), target, intent(in) :: data
      type(phase_clock_t), intent(inout) :: clock
      type(result_record_t), intent(out) :: rec
      logical, intent(out) :: converged
      integer, intent(out) :: exit_code
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t), target :: single
      type(mesh_t) :: current, fine, piece
      type(refinement_map_t) :: map
      type(adapt_step_t), allocatable :: steps(:)
      real(dp), allocatable :: indicators(:), fields(:, :), nodal(:, :), eta(:)
      logical, allocatable :: marked(:)
      character(len=:), allocatable :: stop_reason
      real(dp) :: t_step, hint
      integer(ip) :: a
      integer :: k
      logical :: solved

      allocate (steps(0))
      k = 1
      t_step = wall_time()
      call solve_mesh(cfg, comm, hierarchy, data, clock, rec, solved, exit_code, err, indicators=indicators)
      if (allocated(err)) return
      call clock%switch(phase_mesh)
      ! the whole first mesh on every rank, as gathered (the serial numbering)
      if (comm%is_root()) call current%init(rec%vertices, rec%triangles, 'adaptive refinement', err, &
                                            diameter=hierarchy%meshes(hierarchy%levels)%diameter)
      call comm%agree(err)
      if (allocated(err)) return
      call share_mesh(comm, current, 'adaptive refinement', err)
      if (.not. allocated(err)) call longest_edge_first(current, err)
      call comm%agree(err)
      if (allocated(err)) return
      do
         call share_step(comm, rec, indicators, fields, eta)
         if (eta(1) <= cfg%adapt%tol) then
            stop_reason = 'eta '//fixed_e(eta(1))//' <= adapt.tol '//format_real(cfg%adapt%tol)
         else if (k >= cfg%adapt%max_steps) then
            stop_reason = 'adapt.max_steps = '//int_text(cfg%adapt%max_steps)//' reached with eta '// &
                          fixed_e(eta(1))//' > adapt.tol '//format_real(cfg%adapt%tol)
         end if
         if (.not. allocated(stop_reason)) then
            marked = dorfler_marking(indicators, cfg%adapt%theta)
            call bisect_marked(current, marked, fine, map, err)
            call comm%agree(err)
            if (allocated(err)) return
            if (fine%nv > cfg%adapt%max_vertices) stop_reason = 'adapt.max_vertices = '// &
               int_text(cfg%adapt%max_vertices)//' reached (the next mesh would have '//int_text(int(fine%nv))// &
               ' vertices) with eta '//fixed_e(eta(1))//' > adapt.tol '//format_real(cfg%adapt%tol)
         end if
         if (comm%is_root()) then
            call append_step(rec, indicators, wall_time() - t_step, steps)
            call report(k, rec, marked, steps(k)%wall_time, allocated(stop_reason))
         end if
         if (allocated(stop_reason)) exit
         nodal = prolonged(map, fields)
         current = fine
         ! this rank's piece of the new mesh, as a user's mesh is distributed at start-up (in
         ! bisection's numbering: numbered along the domain instead, the pacman benchmark's
         ! meshes of up to 6.5·10^4 vertices ran no faster, and each step paid a second mesh_t%init)
         if (comm%size > 1) then
            call distribute_coarse(comm, current, piece, err)
            if (allocated(err)) return
            nodal = nodal([(piece%global_vertex_of(a), a=1, piece%nv)], :)
         else
            piece = current
         end if
         call single%init(piece, 0, err)
         call comm%agree(err)
         if (allocated(err)) return
         call single%meshes(0)%drop_refinement_tables()
         call piece%free()
         k = k + 1
         t_step = wall_time()
         call clock%switch(phase_assembly)
         hint = eta(2)*sqrt(real(size(fields, 1), dp)/real(current%nv, dp))
         call solve_mesh(cfg, comm, single, data, clock, rec, solved, exit_code, err, nodal=nodal, &
                         indicators=indicators, eta_disc_hint=hint)
         if (allocated(err)) return
         call clock%switch(phase_mesh)
      end do
      converged = solved .and. eta(1) <= cfg%adapt%tol
      if (comm%is_root()) then
         rec%status = 'adapt: '//stop_reason//' after '//int_text(k)//' steps; last solve: '//rec%status
         call move_alloc(steps, rec%adapt)
      end if
   end subroutine adapt_mesh

   !> What marking and interpolation need, identical on every rank: the element indicators
   !> and the nodal u1, u2, λ (nv, 3) of the whole mesh, and η and η_disc, from rank 0's
   !> gathered record.
   !> Collective.
   subroutine share_step(comm, rec, indicators, fields, eta)
      type(comm_t), intent(in) :: comm
      type(result_record_t), intent(in) :: rec
      real(dp), allocatable, intent(inout) :: indicators(:)
      real(dp), allocatable, intent(out) :: fields(:, :), eta(:)

      if (comm%is_root()) then
         fields = reshape([rec%u1, rec%u2, rec%lambda], [size(rec%u1), 3])
         eta = [rec%eta_total, rec%eta_disc]
      end if
      if (comm%size == 1) return
      call comm%bcast(indicators)
      call comm%bcast(fields)
      call comm%bcast(eta)
   end subroutine share_step

   !> The step just solved (rec, its element indicators) appended to `steps`.
   subroutine append_step(rec, indicators, seconds, steps)
      type(result_record_t), intent(in) :: rec
      real(dp), intent(in) :: indicators(:)
      real(dp), intent(in) :: seconds
      type(adapt_step_t), allocatable, intent(inout) :: steps(:)

      type(adapt_step_t) :: step

      step%vertices = rec%vertices
      step%triangles = rec%triangles
      step%u1 = rec%u1
      step%u2 = rec%u2
      step%lambda = rec%lambda
      step%eta_disc_k = indicators
      step%eta = rec%eta_total
      step%eta_disc = rec%eta_disc
      step%eta_lin = rec%eta_lin
      step%eta_alg = rec%eta_alg
      step%energy_error = rec%energy_error_total
      step%wall_time = seconds
      step%newton_iterations = rec%newton_iterations
      step%gmres_iterations = rec%gmres_iterations
      steps = [steps, step]
   end subroutine append_step

   !> Nodal fields (nv, k) interpolated to the bisected mesh: a new vertex is the midpoint of a
   !> coarse edge, so P1 interpolation is exact there (nested spaces).
   function prolonged(map, fields) result(nodal)
      type(refinement_map_t), intent(in) :: map
      real(dp), intent(in) :: fields(:, :)
      real(dp), allocatable :: nodal(:, :)

      integer(ip) :: a

      allocate (nodal(size(map%vertex_parents, 2), size(fields, 2)))
      do a = 1, size(map%vertex_parents, 2, kind=ip)
         nodal(a, :) = 0.5_dp*(fields(map%vertex_parents(1, a), :) + fields(map%vertex_parents(2, a), :))
      end do
   end function prolonged

   subroutine report(k, rec, marked, seconds, last)
      integer, intent(in) :: k
      type(result_record_t), intent(in) :: rec
      logical, allocatable, intent(in) :: marked(:)
      real(dp), intent(in) :: seconds
      logical, intent(in) :: last

      character(len=:), allocatable :: line

      line = 'adapt: step '//int_text(k)//': '//int_text(size(rec%vertices, 2))//' vertices, eta '// &
             fixed_e(rec%eta_total)//' (disc '//fixed_e(rec%eta_disc)//', lin '//fixed_e(rec%eta_lin)// &
             ', alg '//fixed_e(rec%eta_alg)//')'
      if (.not. ieee_is_nan(rec%energy_error_total)) line = line//', energy error '// &
                                                                   fixed_e(rec%energy_error_total)
      if (.not. last .and. allocated(marked)) line = line//', '//int_text(count(marked))//' marked'
      write (output_unit, '(a)') line//', '//fixed(seconds, 2)//' s'
   end subroutine report

   !> x in the form 1.234e-03.
   function fixed_e(x) result(text)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: text

      character(len=16) :: buffer

      write (buffer, '(es10.3)') x
      text = trim(adjustl(buffer))
   end function fixed_e
end module twomem_app_adapt
