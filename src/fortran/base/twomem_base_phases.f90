!> Where a run spends its time and memory: a clock that is always in exactly one phase (mesh,
!> assembly, solve, estimators, exact error, output) and charges the wall time since the last
!> switch to it, together with the peak resident memory reached by the end of each phase (the
!> operating system only reports the peak so far, so a phase's value includes every earlier
!> one). The run prints the table at the end and stores it in the result file; benchmarks read
!> it from there instead of timing whole processes.
module twomem_base_phases
   use twomem_base_kinds, only: dp, i8
   use twomem_base_timer, only: wall_time
   use twomem_base_system, only: peak_memory_kib
   implicit none
   private

   public :: phase_clock_t, n_phases, phase_names
   public :: phase_mesh, phase_assembly, phase_solve, phase_estimators, phase_error, phase_output

   integer, parameter :: n_phases = 6
   integer, parameter :: phase_mesh = 1, phase_assembly = 2, phase_solve = 3, phase_estimators = 4, &
                         phase_error = 5, phase_output = 6
   character(len=*), parameter :: phase_names(n_phases) = [character(len=10) :: 'mesh', 'assembly', 'solve', &
                                                           'estimators', 'error', 'output']

   type :: phase_clock_t
      real(dp) :: seconds(n_phases) = 0.0_dp
      integer(i8) :: peak_kib(n_phases) = 0
      integer :: current = 0
      real(dp) :: since = 0.0_dp, started = 0.0_dp
   contains
      procedure :: start
      procedure :: switch
      procedure :: charge
      procedure :: total
      procedure :: table
   end type phase_clock_t

contains

   !> Start the run's clock in `phase`.
   subroutine start(self, phase)
      class(phase_clock_t), intent(inout) :: self
      integer, intent(in) :: phase

      self%seconds = 0.0_dp
      self%peak_kib = 0
      self%started = wall_time()
      self%since = self%started
      self%current = phase
   end subroutine start

   !> Close the current phase and continue in `phase`.
   subroutine switch(self, phase)
      class(phase_clock_t), intent(inout) :: self
      integer, intent(in) :: phase

      real(dp) :: now

      now = wall_time()
      if (self%current > 0) then
         self%seconds(self%current) = self%seconds(self%current) + (now - self%since)
         self%peak_kib(self%current) = peak_memory_kib()
      end if
      self%since = now
      self%current = phase
   end subroutine switch

   !> Move `seconds` already counted in the current phase to `phase` (work measured inside
   !> another phase, such as estimator evaluations inside the Newton loop).
   subroutine charge(self, phase, seconds)
      class(phase_clock_t), intent(inout) :: self
      integer, intent(in) :: phase
      real(dp), intent(in) :: seconds

      if (self%current <= 0 .or. phase == self%current) return
      self%seconds(phase) = self%seconds(phase) + seconds
      self%since = self%since + seconds
      self%peak_kib(phase) = max(self%peak_kib(phase), peak_memory_kib())
   end subroutine charge

   !> Wall time since `start`.
   real(dp) function total(self)
      class(phase_clock_t), intent(in) :: self

      total = wall_time() - self%started
   end function total

   !> The table printed at the end of a run, one line per phase that took any time.
   subroutine table(self, lines)
      class(phase_clock_t), intent(in) :: self
      character(len=64), allocatable, intent(out) :: lines(:)

      real(dp) :: all
      integer :: i

      all = max(sum(self%seconds), tiny(1.0_dp))
      lines = [character(len=64) :: 'phase          seconds   share   peak MiB']
      do i = 1, n_phases
         if (self%seconds(i) <= 0.0_dp) cycle
         lines = [lines, row(phase_names(i), self%seconds(i), 100*self%seconds(i)/all, self%peak_kib(i))]
      end do
      lines = [lines, row('total', all, 100.0_dp, maxval(self%peak_kib))]

   contains

      function row(name, seconds, share, kib) result(line)
         character(len=*), intent(in) :: name
         real(dp), intent(in) :: seconds, share
         integer(i8), intent(in) :: kib
         character(len=64) :: line

         character(len=10) :: label

         label = name
         write (line, '(a10,f12.3,f7.1,"%",f11.1)') label, seconds, share, real(kib, dp)/1024
      end function row
   end subroutine table
end module twomem_base_phases
