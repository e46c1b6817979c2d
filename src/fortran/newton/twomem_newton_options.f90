!> What a Newton solve is asked and what it answers: the options (the method, the C-function,
!> the stopping tests, GMRES's settings, as kinds of `twomem_base_options` and numbers: the
!> solver never sees an input word), the result with the integer reason it ended by and that
!> reason's words (`newton_status`, the status of result files and messages), and ν when the case
!> leaves it to the program (`automatic_every`).
module twomem_newton_options
   use twomem_base_kinds, only: dp
   use twomem_base_options, only: c_function_min, c_function_fb, method_direct, method_adaptive, &
      forcing_finish, precond_mg
   use twomem_linalg_gmres, only: gmres_options_t, gmres_reason_text
   use twomem_newton_history, only: history_t
   implicit none
   private

   public :: newton_options_t, newton_result_t, automatic_every, newton_status
   public :: newton_running, newton_converged, newton_iteration_limit, newton_gmres_non_finite_correction, &
             newton_gmres_non_finite_iterate, newton_round_off_floor, newton_cycling

   !> How a Newton solve ended (newton_running while it goes on)
   integer, parameter :: newton_running = 0, newton_converged = 1, newton_iteration_limit = 2, &
                         newton_gmres_non_finite_correction = 3, newton_gmres_non_finite_iterate = 4, &
                         newton_round_off_floor = 5, newton_cycling = 6

   type :: newton_options_t
      !> c_function_min or c_function_fb
      integer :: cfun = c_function_min
      !> method_direct (UMFPACK), method_gmres or method_adaptive (GMRES, estimator-based stopping)
      integer :: linear = method_direct
      !> adaptive stopping: γ_lin, γ_alg and the local criteria instead of the global ones
      real(dp) :: gamma_lin = 0.3_dp, gamma_alg = 0.3_dp
      logical :: local_criteria = .false.
      !> adaptive method: a check computes η_lin first, then η_disc and then the rest only while
      !> the Newton test can still hold (estimate.checks = 'predicted'; check_schedule_t)
      logical :: predicted_checks = .true.
      !> a prediction of η_disc at the start, for the first predicted check (check_schedule_t):
      !> an adaptive refinement step's, from the previous mesh's; −1: none
      real(dp) :: eta_disc_hint = -1
      integer :: max_it = 100
      real(dp) :: tol = 1.0e-10_dp
      logical :: line_search = .false.
      !> Fischer–Burmeister: Newton-min (active-set) steps once the contact set settles
      logical :: fb_active_set = .true.
      !> GMRES: forcing_paper (algebraic ≤ linearization residual), forcing_finish (the same until
      !> the iterate's contact set is the step's, then on to tol) or forcing_fixed (gmres%rtol)
      integer :: forcing = forcing_finish
      !> precond_mg (block elimination with multigrid), precond_ilu0, precond_jacobi, precond_none
      integer :: precond = precond_mg
      type(gmres_options_t) :: gmres
      logical :: verbose = .true.
   end type newton_options_t

   type :: newton_result_t
      !> the iterate [X1; X2; X3] at interior vertices
      real(dp), allocatable :: x(:)
      integer :: iterations = 0
      integer :: linear_iterations = 0
      logical :: converged = .false.
      !> newton_converged or why not (newton_*), and its words with the account of failed GMRES
      !> solves, if any
      integer :: reason = newton_running
      character(len=:), allocatable :: status
      type(history_t) :: history
   end type newton_result_t

contains

   !> ν, the GMRES iterations between two checks of the inner stopping test, when the case
   !> leaves it to the program (estimate.every = 0). ILU(0) takes the paper's 10. With the
   !> multigrid preconditioner a Newton step needs one to three iterations, so each counts:
   !> Newton's inexact GMRES checks after every one (a check costs one residual, and stopping
   !> as soon as the algebraic residual is below the linearization residual saves iterations
   !> without costing Newton steps). So does Fischer–Burmeister finished by active-set steps
   !> (`fb_active_set`): its inexact first steps hand over to active-set steps within one or
   !> two steps, and the earlier stop shortens them (docs/input.md, `estimate.every`).
   !> Fischer–Burmeister throughout keeps 3: its inexact steps wander between contact sets with
   !> ν = 1 (more finest-level Newton steps), and so does the adaptive method, whose checks may
   !> each be an evaluation of the estimators.
   pure integer function automatic_every(linear, cfun, precond, fb_active_set) result(every)
      integer, intent(in) :: linear, cfun, precond
      logical, intent(in) :: fb_active_set

      if (precond /= precond_mg) then
         every = 10
      else if (linear == method_adaptive .or. (cfun == c_function_fb .and. .not. fb_active_set)) then
         every = 3
      else
         every = 1
      end if
   end function automatic_every

   !> The words of `reason` (result files and messages show them); `gmres_reason` is how the
   !> last GMRES solve ended, which a breakdown names.
   function newton_status(reason, gmres_reason) result(text)
      integer, intent(in) :: reason, gmres_reason
      character(len=:), allocatable :: text

      select case (reason)
      case (newton_converged)
         text = 'converged'
      case (newton_iteration_limit)
         text = 'not converged: iteration limit newton.max_it reached'
      case (newton_gmres_non_finite_correction)
         text = 'not converged: GMRES broke down with a non-finite correction (the iterate before it is kept)'
      case (newton_gmres_non_finite_iterate)
         text = 'not converged: GMRES broke down ('//gmres_reason_text(gmres_reason)//') with a non-finite iterate'
      case (newton_round_off_floor)
         text = 'not converged: stagnation (active set unchanged, residual above newton.tol: round-off floor reached)'
      case (newton_cycling)
         text = 'not converged: stagnation (Newton-min cycles between active sets)'
      case default
         text = 'not converged: running'
      end select
   end function newton_status
end module twomem_newton_options
