!> The loop every fuzz target shares: settings from the environment, the scratch file an input
!> is written to, the clock, the tally and the verdict. Input number i of a run is always the
!> same text for the same seed (its random stream is derived from the seed and i), so a failure
!> is reproduced with TWOMEM_FUZZ_FIRST=i TWOMEM_FUZZ_COUNT=1 and the same seed.
!>
!>   TWOMEM_FUZZ_SEED            seed of the generator (default 1)
!>   TWOMEM_FUZZ_COUNT           number of inputs (default 2000)
!>   TWOMEM_FUZZ_FIRST           number of the first input (default 0)
!>   TWOMEM_FUZZ_INPUT_SECONDS   wall time one input may take before it counts as a hang (5)
!>   TWOMEM_TEST_TMP             scratch directory (required)
module fuzz_harness
   use, intrinsic :: iso_fortran_env, only: output_unit
   use twomem_base_kinds, only: dp, i8
   use fuzz_random, only: rng_t
   implicit none
   private

   public :: settings_t, fuzz_target_t, load_settings, run_fuzz, write_samples
   public :: write_bytes, read_bytes, env_text

   !> A parser under test: it makes input number i from its random stream, and it feeds a text
   !> (written to `path`) to the real parsing code and judges the answer.
   type, abstract :: fuzz_target_t
      character(len=:), allocatable :: name
      !> file name extension of its inputs, '.msh' or '.nml'
      character(len=:), allocatable :: extension
   contains
      procedure(generate_interface), deferred :: generate
      procedure(try_interface), deferred :: try
   end type fuzz_target_t

   abstract interface
      subroutine generate_interface(self, rng, text)
         import :: fuzz_target_t, rng_t
         class(fuzz_target_t), intent(in) :: self
         type(rng_t), intent(inout) :: rng
         character(len=:), allocatable, intent(out) :: text
      end subroutine generate_interface

      !> `accepted`: the parser took the input; `problem`: '' or the contract it broke;
      !> `message`: the parser's error message, if it gave one.
      subroutine try_interface(self, path, text, accepted, problem, message)
         import :: fuzz_target_t
         class(fuzz_target_t), intent(in) :: self
         character(len=*), intent(in) :: path, text
         logical, intent(out) :: accepted
         character(len=:), allocatable, intent(out) :: problem, message
      end subroutine try_interface
   end interface

   type :: settings_t
      integer(i8) :: seed = 1
      integer(i8) :: count = 2000
      integer(i8) :: first = 0
      real(dp) :: input_seconds = 5.0_dp
      !> scratch directory, without a trailing slash
      character(len=:), allocatable :: tmp
   end type settings_t

   !> What a run saw: how many inputs each parser accepted and rejected, the contract violations,
   !> and the slowest input.
   type :: tally_t
      character(len=:), allocatable :: target
      integer(i8) :: n = 0, accepted = 0, rejected = 0, failures = 0
      real(dp) :: slowest = 0.0_dp
      integer(i8) :: slowest_input = -1
   contains
      procedure :: record
      procedure :: fail
      procedure :: progress
      procedure :: report
   end type tally_t

contains

   !> Inputs first .. first+count-1 of `target`, each written to one scratch file and parsed;
   !> `passed` is false if any broke the contract or took too long. A crash or a hang leaves the
   !> input that caused it in the scratch file, whose name is printed first.
   subroutine run_fuzz(target, s, passed)
      class(fuzz_target_t), intent(in) :: target
      type(settings_t), intent(in) :: s
      logical, intent(out) :: passed

      type(tally_t) :: tally
      type(rng_t) :: rng
      character(len=:), allocatable :: text, path, problem, message, kept
      character(len=24) :: buf
      integer(i8) :: i
      logical :: accepted
      real(dp) :: start

      tally%target = target%name
      path = s%tmp//'/fuzz-'//target%name//'-current'//target%extension
      write (output_unit, '(a)') target%name//': inputs go to '//path// &
         ' (a crash or hang leaves the culprit there)'
      do i = s%first, s%first + s%count - 1
         call rng%init(s%seed, i)
         call target%generate(rng, text)
         call write_bytes(path, text)
         start = wall_seconds()
         call target%try(path, text, accepted, problem, message)
         call tally%record(i, accepted, wall_seconds() - start)
         if (len(problem) > 0) then
            write (buf, '(i0)') i
            kept = s%tmp//'/fuzz-'//target%name//'-failure-'//trim(buf)//target%extension
            call write_bytes(kept, text)
            if (allocated(message)) then
               call tally%fail(i, problem, kept, message)
            else
               call tally%fail(i, problem, kept)
            end if
         end if
         if (modulo(i - s%first + 1, 10000_i8) == 0) call tally%progress()
      end do
      call tally%report(s, passed)
   end subroutine run_fuzz

   !> Write inputs first .. first+count-1 to `dir` as <name>-<i><extension>, without parsing
   !> them: samples for the end-to-end test of the executable.
   subroutine write_samples(target, s, dir)
      class(fuzz_target_t), intent(in) :: target
      type(settings_t), intent(in) :: s
      character(len=*), intent(in) :: dir

      type(rng_t) :: rng
      character(len=:), allocatable :: text
      character(len=24) :: buf
      integer(i8) :: i

      do i = s%first, s%first + s%count - 1
         call rng%init(s%seed, i)
         call target%generate(rng, text)
         write (buf, '(i0)') i
         call write_bytes(dir//'/'//target%name//'-'//trim(buf)//target%extension, text)
      end do
   end subroutine write_samples

   !> Settings from the environment; `ok` is false (with a message printed) when something
   !> required is missing or a number does not parse.
   subroutine load_settings(s, ok)
      type(settings_t), intent(out) :: s
      logical, intent(out) :: ok

      ok = .true.
      s%tmp = env_text('TWOMEM_TEST_TMP')
      if (len(s%tmp) == 0) then
         write (output_unit, '(a)') 'twomem_fuzz: TWOMEM_TEST_TMP is not set (run through ctest)'
         ok = .false.
         return
      end if
      call env_int('TWOMEM_FUZZ_SEED', s%seed, ok)
      if (ok) call env_int('TWOMEM_FUZZ_COUNT', s%count, ok)
      if (ok) call env_int('TWOMEM_FUZZ_FIRST', s%first, ok)
      if (ok) call env_real('TWOMEM_FUZZ_INPUT_SECONDS', s%input_seconds, ok)
   end subroutine load_settings

   function env_text(name) result(value)
      character(len=*), intent(in) :: name
      character(len=:), allocatable :: value

      integer :: length, stat

      call get_environment_variable(name, length=length, status=stat)
      if (stat /= 0 .or. length == 0) then
         value = ''
         return
      end if
      allocate (character(len=length) :: value)
      call get_environment_variable(name, value)
   end function env_text

   subroutine env_int(name, value, ok)
      character(len=*), intent(in) :: name
      integer(i8), intent(inout) :: value
      logical, intent(out) :: ok

      character(len=:), allocatable :: text
      integer :: ios

      ok = .true.
      text = env_text(name)
      if (len(text) == 0) return
      read (text, *, iostat=ios) value
      if (ios /= 0 .or. value < 0) then
         write (output_unit, '(a)') 'twomem_fuzz: '//name//' must be a non-negative integer, got "'//text//'"'
         ok = .false.
      end if
   end subroutine env_int

   subroutine env_real(name, value, ok)
      character(len=*), intent(in) :: name
      real(dp), intent(inout) :: value
      logical, intent(out) :: ok

      character(len=:), allocatable :: text
      integer :: ios

      ok = .true.
      text = env_text(name)
      if (len(text) == 0) return
      read (text, *, iostat=ios) value
      if (ios /= 0 .or. .not. value > 0.0_dp) then
         write (output_unit, '(a)') 'twomem_fuzz: '//name//' must be a positive number, got "'//text//'"'
         ok = .false.
      end if
   end subroutine env_real

   !> Write `text` byte for byte (stream access: no record markers, no added newline).
   subroutine write_bytes(path, text)
      character(len=*), intent(in) :: path, text

      integer :: unit

      open (newunit=unit, file=path, access='stream', form='unformatted', status='replace', &
            action='write')
      write (unit) text
      close (unit)
   end subroutine write_bytes

   !> The whole file `path`; stops the run if it cannot be read (a seed file is missing).
   function read_bytes(path) result(text)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: text

      integer :: unit, ios, size_bytes
      character(len=512) :: msg

      open (newunit=unit, file=path, access='stream', form='unformatted', status='old', &
            action='read', iostat=ios, iomsg=msg)
      if (ios /= 0) then
         write (output_unit, '(a)') 'twomem_fuzz: cannot read '//path//': '//trim(msg)
         error stop 2
      end if
      inquire (unit=unit, size=size_bytes)
      allocate (character(len=size_bytes) :: text)
      if (size_bytes > 0) read (unit) text
      close (unit)
   end function read_bytes

   real(dp) function wall_seconds()
      integer(i8) :: count, rate

      call system_clock(count, rate)
      wall_seconds = real(count, dp)/real(rate, dp)
   end function wall_seconds

   !> Count one input that took `seconds`, accepted or rejected.
   subroutine record(self, input, accepted, seconds)
      class(tally_t), intent(inout) :: self
      integer(i8), intent(in) :: input
      logical, intent(in) :: accepted
      real(dp), intent(in) :: seconds

      self%n = self%n + 1
      if (accepted) then
         self%accepted = self%accepted + 1
      else
         self%rejected = self%rejected + 1
      end if
      if (seconds > self%slowest) then
         self%slowest = seconds
         self%slowest_input = input
      end if
   end subroutine record

   !> A contract violation: printed at once with the input number and where the input is kept.
   subroutine fail(self, input, problem, kept, message)
      class(tally_t), intent(inout) :: self
      integer(i8), intent(in) :: input
      character(len=*), intent(in) :: problem, kept
      character(len=*), intent(in), optional :: message

      character(len=24) :: buf

      self%failures = self%failures + 1
      write (buf, '(i0)') input
      write (output_unit, '(a)') 'FAIL '//self%target//' input '//trim(buf)//': '// &
         printable(problem, 300)//' (input kept as '//kept//')'
      if (present(message)) write (output_unit, '(a)') '     message: '//printable(message, 300)
   end subroutine fail

   !> A line every 10 000 inputs, so a long run shows it is alive.
   subroutine progress(self)
      class(tally_t), intent(in) :: self

      write (output_unit, '(a,": ",i0," inputs, ",i0," contract violations so far")') &
         self%target, self%n, self%failures
      flush (output_unit)
   end subroutine progress

   !> The summary line; `passed` unless an input broke the contract or took too long.
   subroutine report(self, s, passed)
      class(tally_t), intent(in) :: self
      type(settings_t), intent(in) :: s
      logical, intent(out) :: passed

      write (output_unit, '(a,": ",i0," inputs (seed ",i0,", first ",i0,"): ",i0," accepted, ",i0, &
           &" rejected, ",i0," contract violations; slowest input ",i0," took ",f0.3," s")') &
         self%target, self%n, s%seed, s%first, self%accepted, self%rejected, self%failures, &
         self%slowest_input, self%slowest
      passed = self%failures == 0 .and. self%n == s%count
      if (self%slowest > s%input_seconds) then
         write (output_unit, '(a,f0.1,a)') 'FAIL '//self%target//': an input took longer than ', &
            s%input_seconds, ' s (TWOMEM_FUZZ_INPUT_SECONDS): a hang in the making'
         passed = .false.
      end if
   end subroutine report

   !> Control characters shown as <hex>, at most `limit` characters, for printing messages.
   function printable(text, limit) result(s)
      character(len=*), intent(in) :: text
      integer, intent(in) :: limit
      character(len=:), allocatable :: s

      character(len=4) :: hex
      integer :: i, c

      s = ''
      do i = 1, min(len(text), limit)
         c = iachar(text(i:i))
         if (c < 32 .or. c == 127) then
            write (hex, '("<",z2.2,">")') c
            s = s//hex
         else
            s = s//text(i:i)
         end if
      end do
      if (len(text) > limit) s = s//'...'
   end function printable
end module fuzz_harness
