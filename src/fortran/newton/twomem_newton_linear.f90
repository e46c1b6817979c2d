!> The linear solve inside a Newton step, behind one type: UMFPACK for the exact method, or
!> restarted GMRES with a preconditioner refreshed from each Newton matrix. Everything that
!> survives between Newton steps (the symbolic factorization, the ILU pattern data, the Krylov
!> workspace) lives here, so the driver only says "solve A x = b, starting from x".
module twomem_newton_linear
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: preconditioner_t, csr_operator_t, identity_preconditioner_t, &
      euclidean_product_t
   use twomem_linalg_ilu0, only: ilu0_preconditioner_t
   use twomem_linalg_jacobi, only: jacobi_preconditioner_t
   use twomem_linalg_umfpack, only: umfpack_solver_t
   use twomem_linalg_gmres, only: gmres_solve, gmres_options_t, gmres_monitor_t, gmres_observer_t, &
      gmres_workspace_t
   implicit none
   private

   public :: linear_step_t

   type :: linear_step_t
      !> 'direct' or 'gmres'
      character(len=8) :: kind = 'direct'
      type(gmres_options_t) :: options
      type(umfpack_solver_t) :: direct
      class(preconditioner_t), allocatable :: prec
      type(gmres_workspace_t) :: workspace
      type(euclidean_product_t) :: dot
      !> the last GMRES solve
      type(gmres_monitor_t) :: monitor
   contains
      procedure :: init => linear_init
      procedure :: solve => linear_solve
   end type linear_step_t

contains

   !> `precond` is 'ilu0', 'jacobi' or 'none' (GMRES only).
   subroutine linear_init(self, kind, precond, options, err)
      class(linear_step_t), intent(inout) :: self
      character(len=*), intent(in) :: kind, precond
      type(gmres_options_t), intent(in) :: options
      type(error_t), allocatable, intent(out) :: err

      self%kind = kind
      self%options = options
      if (allocated(self%prec)) deallocate (self%prec)
      if (kind /= 'gmres') return
      select case (precond)
      case ('ilu0')
         allocate (ilu0_preconditioner_t :: self%prec)
      case ('jacobi')
         allocate (jacobi_preconditioner_t :: self%prec)
      case ('none')
         allocate (identity_preconditioner_t :: self%prec)
      case default
         call make_error(err, exit_bad_input, 'gmres.precond', 'unknown preconditioner '''//precond//'''')
      end select
   end subroutine linear_init

   !> Solve A x = b; x holds the initial guess on entry (used by GMRES). `atol` > 0 adds an
   !> absolute target on ‖b − A x‖ for GMRES; the observer sees GMRES iterates.
   subroutine linear_solve(self, a, b, x, err, atol, observer)
      class(linear_step_t), intent(inout) :: self
      type(csr_t), target, intent(in) :: a
      real(dp), intent(in) :: b(:)
      real(dp), intent(inout) :: x(:)
      type(error_t), allocatable, intent(out) :: err
      real(dp), intent(in), optional :: atol
      class(gmres_observer_t), intent(inout), optional :: observer

      type(csr_operator_t) :: op
      type(gmres_options_t) :: options

      if (self%kind == 'direct') then
         call self%direct%factor(a, err)
         if (allocated(err)) return
         call self%direct%solve(a, b, x, err)
         return
      end if
      call self%prec%setup(a, err)
      if (allocated(err)) return
      op%a => a
      options = self%options
      if (present(atol)) options%atol = atol
      call gmres_solve(op, self%prec, self%dot, b, x, options, self%monitor, err, observer, self%workspace)
   end subroutine linear_solve
end module twomem_newton_linear
