!> The linear solve inside a Newton step, behind one type: UMFPACK for the exact method, or
!> restarted GMRES with a preconditioner refreshed from each Newton matrix: the block
!> elimination with multigrid ('mg'), ILU(0), Jacobi or none. Everything that survives between
!> Newton steps (the symbolic factorization, the multigrid hierarchies, the ILU pattern data,
!> the Krylov workspace) lives here, so the driver only says "solve A x = b, starting from x".
!> It also keeps the account of GMRES solves that ended without converging, which the driver
!> reports when Newton itself fails.
module twomem_newton_linear
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_base_options, only: precond_mg, precond_ilu0, precond_jacobi, precond_none
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: preconditioner_t, csr_operator_t, identity_preconditioner_t
   use twomem_linalg_ilu0, only: ilu0_preconditioner_t
   use twomem_linalg_jacobi, only: jacobi_preconditioner_t
   use twomem_linalg_gathered_solve, only: gathered_solver_t
   use twomem_linalg_multigrid, only: multigrid_options_t, multigrid_transfer_t
   use twomem_linalg_gmres, only: gmres_solve, gmres_options_t, gmres_monitor_t, gmres_observer_t, &
      gmres_workspace_t, gmres_stopped_by_observer, gmres_reason_text, gmres_not_solved
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_newton_system, only: newton_system_t, newton_operator_t
   use twomem_newton_elimination, only: elimination_preconditioner_t
   implicit none
   private

   public :: linear_step_t, needs_matrix
   public :: solver_direct, solver_gmres

   integer, parameter :: solver_direct = 1, solver_gmres = 2

   type :: linear_step_t
      !> solver_direct or solver_gmres
      integer :: kind = solver_direct
      type(gmres_options_t) :: options
      !> UMFPACK on the whole Newton matrix (gathered on rank 0 in a distributed run)
      type(gathered_solver_t) :: direct
      class(preconditioner_t), allocatable :: prec
      type(gmres_workspace_t) :: workspace
      !> the last GMRES solve
      type(gmres_monitor_t) :: monitor
      !> the last solve was matrix-free GMRES: monitor%final_residual is ‖b − A x‖ with A applied
      !> by the system's own `apply`, the same bits as the caller would compute
      logical :: residual_known = .false.
      !> GMRES solves that ended neither converged nor stopped by the observer, and the last reason
      integer :: failures = 0
      integer :: failure_reason = gmres_not_solved
   contains
      procedure :: init => linear_init
      procedure :: solve => linear_solve
      procedure :: failure_note
   end type linear_step_t

contains

   !> Whether a solve with this solver and preconditioner needs the assembled Newton matrix.
   pure logical function needs_matrix(kind, precond)
      integer, intent(in) :: kind, precond

      needs_matrix = kind == solver_direct .or. precond /= precond_mg
   end function needs_matrix

   !> `precond` matters for GMRES only. precond_mg needs the problem and the transfers of its
   !> hierarchy, the problem's mesh being level `level` (0: the exact elimination); both must
   !> outlive the solver. Collective.
   subroutine linear_init(self, kind, precond, options, problem, transfer, level, err)
      class(linear_step_t), intent(inout) :: self
      integer, intent(in) :: kind, precond
      type(gmres_options_t), intent(in) :: options
      type(discrete_problem_t), target, intent(in) :: problem
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      integer, intent(in) :: level
      type(error_t), allocatable, intent(out) :: err

      type(multigrid_options_t) :: mg_options

      self%kind = kind
      self%options = options
      self%failures = 0
      if (allocated(self%prec)) deallocate (self%prec)
      if (kind == solver_direct) then
         call init_direct(self%direct, problem)
         return
      end if
      select case (precond)
      case (precond_mg)
         allocate (elimination_preconditioner_t :: self%prec)
         select type (prec => self%prec)
         type is (elimination_preconditioner_t)
            call prec%init(problem, transfer, level, mg_options, err)
         end select
      case (precond_ilu0)
         allocate (ilu0_preconditioner_t :: self%prec)
         select type (prec => self%prec)
         type is (ilu0_preconditioner_t)
            ! the paper's preconditioner in the mesh's vertex order, whatever the unknowns' order
            call prec%set_order(block_vertex_keys(problem))
         end select
      case (precond_jacobi)
         allocate (jacobi_preconditioner_t :: self%prec)
      case (precond_none)
         allocate (identity_preconditioner_t :: self%prec)
      case default
         call make_error(err, exit_bad_input, 'gmres.precond', 'unknown preconditioner')
      end select
   end subroutine linear_init

   !> The gathered direct solver of the Newton system, its unknowns keyed by block_vertex_keys.
   subroutine init_direct(direct, problem)
      type(gathered_solver_t), intent(inout) :: direct
      type(discrete_problem_t), intent(in) :: problem

      call direct%init(problem%halo%comm, block_vertex_keys(problem), &
                       [problem%halo%owned, problem%halo%owned, problem%halo%owned])
   end subroutine init_direct

   !> Unknown i of block k of the Newton system is keyed (k − 1) M + (whole-mesh vertex of i),
   !> M the largest vertex number: in key order the system keeps the block order (X1, X2, X3)
   !> and, within a block, the vertex order of the whole mesh. Collective.
   function block_vertex_keys(problem) result(keys)
      type(discrete_problem_t), intent(in) :: problem
      integer(ip), allocatable :: keys(:)

      integer(ip) :: m

      m = problem%halo%comm%max(maxval([0_ip, problem%global]))
      keys = [problem%global, m + problem%global, 2*m + problem%global]
   end function block_vertex_keys

   !> Solve A x = b for the current linearization of `sys`; x holds the initial guess on entry
   !> (used by GMRES). `atol` > 0 adds an absolute target on ‖b − A x‖ for GMRES; the observer
   !> sees GMRES iterates.
   subroutine linear_solve(self, sys, b, x, err, atol, observer)
      class(linear_step_t), intent(inout) :: self
      type(newton_system_t), target, intent(in) :: sys
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      type(error_t), allocatable, intent(out) :: err
      real(dp), intent(in), optional :: atol
      class(gmres_observer_t), intent(inout), optional :: observer

      type(csr_operator_t) :: matrix
      type(newton_operator_t) :: matrix_free
      type(gmres_options_t) :: options

      self%residual_known = .false.
      if (self%kind == solver_direct) then
         call self%direct%factor(sys%a, err)
         if (allocated(err)) return
         call self%direct%solve(b, x, err)
         return
      end if
      options = self%options
      if (present(atol)) options%atol = atol
      select type (prec => self%prec)
      type is (elimination_preconditioner_t)
         call prec%set_linearization(sys%da, sys%db, err)
         if (allocated(err)) return
         matrix_free%sys => sys
         call gmres_solve(matrix_free, prec, sys%dot, b, x, options, self%monitor, err, observer, self%workspace)
         self%residual_known = .true.
      class default
         call prec%setup(sys%a, err)
         if (allocated(err)) return
         matrix%a => sys%a
         call gmres_solve(matrix, prec, sys%dot, b, x, options, self%monitor, err, observer, self%workspace)
      end select
      if (allocated(err)) return
      if (.not. self%monitor%converged .and. self%monitor%reason /= gmres_stopped_by_observer) then
         self%failures = self%failures + 1
         self%failure_reason = self%monitor%reason
      end if
   end subroutine linear_solve

   !> ' (N GMRES solves ended by 'reason')' when some did, else ''.
   function failure_note(self) result(note)
      class(linear_step_t), intent(in) :: self
      character(len=:), allocatable :: note

      character(len=16) :: count_text

      note = ''
      if (self%failures == 0) return
      write (count_text, '(i0)') self%failures
      note = ' ('//trim(count_text)//' GMRES solves ended by '''//gmres_reason_text(self%failure_reason)//''')'
   end function failure_note
end module twomem_newton_linear
