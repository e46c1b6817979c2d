!> Newton on the levels of the hierarchy: on the finest level alone from the paper's initial
!> guess (g, 0, 0), or by nested iteration, from T_0 up, each level's solution interpolated as
!> the next one's initial guess, its contact set settled vertex by vertex where interpolation
!> broke complementarity (`twomem_newton_settle`), which keeps the Newton count on the finest
!> level nearly independent of the mesh. Nested iteration starts below the coarsest mesh too
!> when that mesh is large (a user's fine mesh given as it is): on meshes coarsened from it
!> (`twomem_app_coarse_meshes`). The multigrid transfers of the whole hierarchy are built once
!> here and serve every level (`twomem_app_transfers`); the caller owns them, so that the
!> estimators' Riesz preconditioner can use them too, through the run's last evaluation.
module twomem_app_levels
   use, intrinsic :: iso_fortran_env, only: output_unit
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: method_direct, method_gmres, method_adaptive, forcing_finish, precond_mg, &
      initial_nested
   use twomem_base_timer, only: wall_time
   use twomem_base_text, only: fixed
   use twomem_base_phases, only: phase_clock_t, phase_assembly, phase_solve
   use twomem_input_config, only: config_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_multigrid, only: multigrid_transfer_t
   use twomem_newton_solver, only: newton_options_t, newton_result_t, newton_observer_t, newton_solve, &
      automatic_every
   use twomem_newton_settle, only: settle_contact
   use twomem_app_transfers, only: hierarchy_transfer
   use twomem_app_coarse_meshes, only: coarse_work_t, coarsened_start, cold_start
   implicit none
   private

   public :: solve_levels, solve_from, coarse_work_t, uses_multigrid

contains

   !> Whether the solves with `options` build multigrid transfers (with algebraic levels below a
   !> large mesh), rather than the one level of a direct or single-level preconditioned solve.
   pure logical function uses_multigrid(options)
      type(newton_options_t), intent(in) :: options

      uses_multigrid = options%precond == precond_mg .and. options%linear /= method_direct
   end function uses_multigrid

   !> Newton for the finest problem p (nested iteration when newton.initial = 'nested'), on the
   !> transfers `transfer` built here. Collective.
   subroutine solve_levels(cfg, comm, hierarchy, data, p, options, clock, transfer, newton, coarse, err, observer)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), intent(in) :: data
      type(discrete_problem_t), target, intent(in) :: p
      type(newton_options_t), intent(in) :: options
      type(phase_clock_t), intent(inout) :: clock
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      type(newton_result_t), intent(out) :: newton
      type(coarse_work_t), intent(out) :: coarse
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), intent(inout), optional :: observer

      type(newton_options_t) :: quiet
      real(dp), allocatable :: fine(:, :), x0(:)
      real(dp) :: t_level
      integer :: l, finest, bottom, shift
      logical :: nested

      finest = hierarchy%levels
      bottom = hierarchy%first_with_unknowns(comm)
      nested = cfg%newton%initial == initial_nested
      call hierarchy_transfer(comm, hierarchy, bottom, p, uses_multigrid(options), transfer, err)
      if (allocated(err)) return
      ! level l of the hierarchy is level l + shift of the transfers
      shift = transfer%algebraic - bottom
      quiet = coarse_options(cfg, options)
      if (.not. nested) then
         x0 = cold_start(p)
         call newton_solve(p, options, x0, newton, err, observer, transfer, finest + shift)
         return
      end if
      if (bottom > 0 .and. comm%is_root()) write (output_unit, '("nested: levels 0..",i0,&
         &" have no interior vertex (the boundary values decide them): starting on level ",i0)') bottom - 1, bottom
      if (finest == bottom) then
         call coarsened_start(hierarchy%meshes(finest), data, p, quiet, comm, x0, coarse, err)
         if (allocated(err)) return
         call newton_solve(p, options, x0, newton, err, observer, transfer, finest + shift)
         return
      end if
      do l = bottom, finest - 1
         t_level = wall_time()
         ! the level's problem and result go at the end of the iteration, not through the finer
         ! solves (level J − 1's: 30 MB at 10⁶ vertices during the finest one)
         block
            type(discrete_problem_t), target :: pl
            type(newton_result_t) :: step

            call clock%switch(phase_assembly)
            call pl%init(hierarchy%meshes(l), data, err, comm)
            call clock%switch(phase_solve)
            if (allocated(err)) return
            if (l == bottom) then
               call coarsened_start(hierarchy%meshes(l), data, pl, quiet, comm, x0, coarse, err)
               if (allocated(err)) return
            else
               x0 = interior_values(pl, fine)
               call settle_contact(pl, x0)
            end if
            call newton_solve(pl, quiet, x0, step, err, transfer=transfer, level=l + shift)
            if (allocated(err)) return
            coarse%newton_iterations = coarse%newton_iterations + step%iterations
            coarse%gmres_iterations = coarse%gmres_iterations + step%linear_iterations
            if (comm%is_root()) then
               write (output_unit, '("nested: level ",i2,": ",i4," Newton steps, ",i6," GMRES iterations (",a,"), ",a, &
                    &" s")') l, step%iterations, step%linear_iterations, step%status, fixed(wall_time() - t_level, 2)
               if (.not. step%converged) write (output_unit, '(a,i0,a)') 'warning: level ', l, &
                  ' did not converge; its iterate still serves as the initial guess of the next level'
            end if
            call interpolate(hierarchy, l, pl, data%g, step%x, fine)
         end block
      end do
      ! the interpolated nodal fields are not kept through the finest solve
      x0 = interior_values(p, fine)
      call settle_contact(p, x0)
      deallocate (fine)
      call newton_solve(p, options, x0, newton, err, observer, transfer, finest + shift)
   end subroutine solve_levels

   !> Newton for the finest problem p from nodal fields (nv, 3) of u1, u2, λ (an interpolated
   !> solution of a coarser mesh of the same domain, as in nested iteration: its contact set
   !> settled first), on the transfers `transfer` built here. Collective.
   subroutine solve_from(comm, hierarchy, p, options, nodal, transfer, newton, err, observer)
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      type(discrete_problem_t), target, intent(in) :: p
      type(newton_options_t), intent(in) :: options
      real(dp), intent(in) :: nodal(:, :)
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      type(newton_result_t), intent(out) :: newton
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), intent(inout), optional :: observer

      real(dp), allocatable :: x0(:)
      integer :: bottom

      bottom = hierarchy%first_with_unknowns(comm)
      call hierarchy_transfer(comm, hierarchy, bottom, p, uses_multigrid(options), transfer, err)
      if (allocated(err)) return
      x0 = interior_values(p, nodal)
      call settle_contact(p, x0)
      call newton_solve(p, options, x0, newton, err, observer, transfer, &
                        hierarchy%levels + transfer%algebraic - bottom)
   end subroutine solve_from

   !> The options of Newton on the coarser levels of nested iteration: quiet, and in an adaptive
   !> run the inexact GMRES (the paper's forcing, finishing the last solve), checked as often as
   !> that method is, since the estimators live on the finest hierarchy.
   function coarse_options(cfg, options) result(quiet)
      type(config_t), intent(in) :: cfg
      type(newton_options_t), intent(in) :: options
      type(newton_options_t) :: quiet

      quiet = options
      quiet%verbose = .false.
      if (quiet%linear == method_adaptive) then
         quiet%linear = method_gmres
         quiet%forcing = forcing_finish
         if (cfg%estimate%every == 0) &
            quiet%gmres%observe_every = automatic_every(quiet%linear, quiet%cfun, quiet%precond, quiet%fb_active_set)
      end if
   end function coarse_options

   !> fine(:, k): the nodal fields u1, u2, λ of level l's solution x, interpolated to level l+1.
   subroutine interpolate(hierarchy, l, pl, g, x, fine)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: l
      type(discrete_problem_t), intent(in) :: pl
      real(dp), intent(in) :: g, x(:)
      real(dp), allocatable, intent(inout) :: fine(:, :)

      real(dp), allocatable :: u(:, :)
      integer :: k

      if (allocated(fine)) deallocate (fine)
      allocate (u(hierarchy%meshes(l)%nv, 3), fine(hierarchy%meshes(l + 1)%nv, 3))
      u(:, 1) = pl%to_nodal(x(1:pl%n), g)
      u(:, 2) = pl%to_nodal(x(pl%n + 1:2*pl%n), 0.0_dp)
      u(:, 3) = pl%to_nodal(x(2*pl%n + 1:), 0.0_dp)
      do k = 1, 3
         call hierarchy%prolong(l + 1, u(:, k), fine(:, k))
      end do
   end subroutine interpolate

   !> [X1; X2; X3] at the interior vertices of `p` from nodal fields (nv, 3).
   function interior_values(p, nodal) result(x)
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: nodal(:, :)
      real(dp), allocatable :: x(:)

      x = [nodal(p%interior, 1), nodal(p%interior, 2), nodal(p%interior, 3)]
   end function interior_values
end module twomem_app_levels
