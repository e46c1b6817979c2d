!> The run's history, one row per recorded point (a Newton step, or every ν GMRES iterations
!> inside one), and the progress line printed for each Newton row. Columns are those of
!> `/history` in docs/output.md plus the residuals; estimators and errors not computed are NaN, so
!> a missing value is never mistaken for a zero.
module twomem_newton_history
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_is_nan
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: history_row_t, history_t, not_computed, print_progress

   type :: history_row_t
      integer :: newton_it = 0
      !> cumulative linear-solver iterations (0 for direct solves)
      integer :: gmres_it = 0
      real(dp) :: eta_disc, eta_lin, eta_alg, eta_total, energy_error
      !> ‖R_lin‖/‖[F;0]‖ and ‖B − A X‖/‖B‖
      real(dp) :: lin_residual, alg_residual
      !> vertices where the a-row (contact) is chosen, and how many changed since the last step
      integer :: active = 0, active_changed = 0
      !> line-search step length of the Newton update (1 = full step)
      real(dp) :: step = 1.0_dp
      !> .true. for a row recorded inside GMRES (every ν iterations), .false. for a Newton step
      logical :: inner = .false.
      !> the paper's local stopping criteria (64a) and (64b) at this iterate, when evaluated
      logical :: local_alg_ok = .false., local_lin_ok = .false.
      real(dp) :: wall_time = 0.0_dp
   contains
      procedure :: take_observations
   end type history_row_t

   type :: history_t
      integer :: n = 0
      type(history_row_t), allocatable :: rows(:)
   contains
      procedure :: append
   end type history_t

contains

   !> A row whose estimator and error columns are NaN until someone computes them.
   function not_computed() result(row)
      type(history_row_t) :: row

      real(dp) :: nan

      nan = ieee_value(1.0_dp, ieee_quiet_nan)
      row%eta_disc = nan
      row%eta_lin = nan
      row%eta_alg = nan
      row%eta_total = nan
      row%energy_error = nan
      row%lin_residual = nan
      row%alg_residual = nan
   end function not_computed

   !> What an observer computed for an iterate (estimators, exact error, local criteria), taken
   !> from another row of the same iterate.
   pure subroutine take_observations(self, from)
      class(history_row_t), intent(inout) :: self
      type(history_row_t), intent(in) :: from

      self%energy_error = from%energy_error
      self%eta_disc = from%eta_disc
      self%eta_lin = from%eta_lin
      self%eta_alg = from%eta_alg
      self%eta_total = from%eta_total
      self%local_alg_ok = from%local_alg_ok
      self%local_lin_ok = from%local_lin_ok
   end subroutine take_observations

   subroutine append(self, row)
      class(history_t), intent(inout) :: self
      type(history_row_t), intent(in) :: row

      type(history_row_t), allocatable :: grown(:)

      if (.not. allocated(self%rows)) allocate (self%rows(16))
      if (self%n == size(self%rows)) then
         allocate (grown(2*self%n))
         grown(1:self%n) = self%rows(1:self%n)
         call move_alloc(grown, self%rows)
      end if
      self%n = self%n + 1
      self%rows(self%n) = row
   end subroutine append

   !> One line per Newton step on standard output (docs/usage.md, *Running a case*).
   subroutine print_progress(row)
      type(history_row_t), intent(in) :: row

      character(len=96) :: err_text

      err_text = ''
      if (.not. ieee_is_nan(row%eta_total)) then
         write (err_text, '("  eta ",es9.3," (disc ",es9.3,", lin ",es9.3,", alg ",es9.3,")")') row%eta_total, &
            row%eta_disc, row%eta_lin, row%eta_alg
      else if (.not. ieee_is_nan(row%eta_disc)) then
         ! an adaptive check that saw the Newton test fail before the algebraic flux
         write (err_text, '("  eta_lin ",es9.3,", eta_disc ",es9.3," (no algebraic part)")') row%eta_lin, row%eta_disc
      else if (.not. ieee_is_nan(row%eta_lin)) then
         ! an adaptive check that saw it fail with the last η_disc
         write (err_text, '("  eta_lin ",es9.3," (no evaluation)")') row%eta_lin
      end if
      if (.not. ieee_is_nan(row%energy_error)) write (err_text, '(a,"  error ",es9.3)') trim(err_text), row%energy_error
      write (output_unit, '("newton ",i4,"  gmres ",i6,"  contact ",i8," (changed ",i7,")  lin-res ",es9.3, &
           &"  alg-res ",es9.3,"  step ",f5.3,a,"  ",f9.2," s")') row%newton_it, row%gmres_it, row%active, &
         row%active_changed, row%lin_residual, row%alg_residual, row%step, trim(err_text), row%wall_time
      flush (output_unit)
   end subroutine print_progress
end module twomem_newton_history
