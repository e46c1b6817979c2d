!> How a GMRES solve ended: `gmres_monitor_t` (iterations, initial and final residual, the
!> residual history and the reason) and the reasons as integer kinds, so that the Newton driver
!> steers on a named constant, with `gmres_reason_text` for the words that messages and result
!> files show.
module twomem_linalg_gmres_monitor
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: gmres_monitor_t, gmres_reason_text
   public :: gmres_not_solved, gmres_converged, gmres_iteration_limit, gmres_breakdown, gmres_stagnation, &
             gmres_stopped_by_observer, gmres_non_finite_correction, gmres_invalid_arguments

   !> How a solve ended (`gmres_monitor_t%reason`; `gmres_reason_text` gives its words).
   !> gmres_non_finite_correction leaves x at the last finite iterate.
   integer, parameter :: gmres_not_solved = 0, gmres_converged = 1, gmres_iteration_limit = 2, &
                         gmres_breakdown = 3, gmres_stagnation = 4, gmres_stopped_by_observer = 5, &
                         gmres_non_finite_correction = 6, gmres_invalid_arguments = 7

   type :: gmres_monitor_t
      integer :: iterations = 0
      integer :: restarts = 0
      !> true residual norms of the initial guess and of the returned x
      real(dp) :: initial_residual = 0.0_dp
      real(dp) :: final_residual = 0.0_dp
      !> the residual estimate at every iteration, initial residual first (iterations + 1)
      real(dp), allocatable :: residual_history(:)
      !> .true. exactly when reason is gmres_converged
      logical :: converged = .false.
      !> how the solve ended: gmres_converged, gmres_iteration_limit, ... (gmres_not_solved
      !> before any)
      integer :: reason = gmres_not_solved
      !> cycles whose Arnoldi estimate met the tolerance while the true residual did not
      integer :: false_convergences = 0
      !> Arnoldi steps that needed the second Gram–Schmidt pass
      integer :: reorthogonalizations = 0
      !> the last cycle ended on an invariant Krylov space
      logical :: happy_breakdown = .false.
   contains
      procedure :: reason_text => monitor_reason_text
   end type gmres_monitor_t

contains

   !> The words of a reason, as messages and result files show them.
   pure function gmres_reason_text(reason) result(text)
      integer, intent(in) :: reason
      character(len=:), allocatable :: text

      select case (reason)
      case (gmres_converged)
         text = 'converged'
      case (gmres_iteration_limit)
         text = 'iteration limit'
      case (gmres_breakdown)
         text = 'breakdown'
      case (gmres_stagnation)
         text = 'stagnation'
      case (gmres_stopped_by_observer)
         text = 'stopped by observer'
      case (gmres_non_finite_correction)
         text = 'non-finite correction'
      case (gmres_invalid_arguments)
         text = 'invalid arguments'
      case default
         text = 'not solved'
      end select
   end function gmres_reason_text

   !> The words of the monitor's reason.
   function monitor_reason_text(self) result(text)
      class(gmres_monitor_t), intent(in) :: self
      character(len=:), allocatable :: text

      text = gmres_reason_text(self%reason)
   end function monitor_reason_text
end module twomem_linalg_gmres_monitor
