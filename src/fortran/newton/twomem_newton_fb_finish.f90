!> Which C-function a Fischer–Burmeister Newton step linearizes (newton.fb_finish =
!> 'active_set', the default; docs/method.md §2). Once an FB step moves the contact set
!> {a ≤ b} by at most `settle_fraction` of its size, the next step linearizes min instead, which
!> imposes u1 = u2 on that set and λ = 0 off it and so lands on the discrete solution at once
!> when the set is right. FB alone converges there only quadratically with a constant
!> ~1/|(a, b)| of the solution, and the first free layer beside the contact zone has a ~ h²,
!> b = 0: four or five steps of the tail measured at every mesh size. A nearly biactive vertex
!> may be guessed on the wrong side (measured at 1.1e6 vertices: 13 vertices, the residual rose
!> to 3e-3); the next step, again an active-set step (a primal–dual active set update), corrects
!> the guess. Active-set steps go on while they change the set, at most three in a row, then FB
!> resumes (an FB step instead of the second active-set step there, from a residual of 1.2e-7,
!> took four more steps instead of two). Active-set steps are judged by the FB merit like any
!> other step (line search) and the stopping test is FB's. Waiting for an FB step that moves no
!> vertex at all cost two steps at 1.1e6 vertices (99, 4, 0 vertices moved by FB's 2nd to 4th
!> steps, each quadratically closer), which the active-set steps do in one.
module twomem_newton_fb_finish
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: fb_finish_t

   !> FB's contact set counts as settled when a step moves at most this share of it. The first
   !> step from nested iteration's interpolated start moves about 0.7% of it (1913 of 269620
   !> vertices at 1.1e6 vertices, 1084 of 67613 at 2.9e5), the next ones a few dozen vertices:
   !> at 1% the active-set steps begin after the first FB step there (bench/scaling.py at 1.1e6
   !> vertices: 4 Newton steps instead of 6 for `membranes`, 4 instead of 5 for `bbbv`).
   real(dp), parameter :: settle_fraction = 0.01_dp
   !> active-set steps in a row at most
   integer, parameter :: max_streak = 3

   type :: fb_finish_t
      !> whether active-set steps may be taken at all (FB with newton.fb_finish = 'active_set')
      logical :: enabled = .false.
      !> the step being taken linearizes min
      logical :: active_set_step = .false.
      integer, private :: streak = 0
      !> what the last step did to the contact set: moved no vertex, moved at most settle_fraction
      logical, private :: settled = .false., nearly_settled = .false.
   contains
      procedure :: next_step
      procedure :: step_moved
   end type fb_finish_t

contains

   !> Decide the kind of the next step (active_set_step).
   subroutine next_step(self)
      class(fb_finish_t), intent(inout) :: self

      if (self%active_set_step) then
         self%streak = self%streak + 1
         self%active_set_step = .not. self%settled .and. self%streak < max_streak
      else
         self%streak = 0
         self%active_set_step = self%enabled .and. self%nearly_settled
      end if
   end subroutine next_step

   !> The step just taken moved `changed` of the `active` vertices of the contact set.
   subroutine step_moved(self, changed, active)
      class(fb_finish_t), intent(inout) :: self
      integer, intent(in) :: changed, active

      self%settled = changed == 0
      self%nearly_settled = changed <= settle_fraction*active
   end subroutine step_moved
end module twomem_newton_fb_finish
