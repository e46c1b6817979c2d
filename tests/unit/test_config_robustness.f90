!> Regression tests for defects in the case input found while fuzzing it (tests/fuzz), by the
!> fuzzer itself or by reading the code it exercised: each is a small input that showed one,
!> checked against the bad-input contract (one short line naming the file or override, exit
!> category 2) or against what a valid input must give.
module test_config_robustness
   use twomem_base_errors, only: exit_bad_input
   use twomem_input_config, only: config_t, string_t, load_config, load_config_text, config_echo
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   use test_config, only: write_case, no_overrides, words, expect_error
   implicit none
   private

   public :: collect_config_robustness

   character, parameter :: nl = new_line('a'), cr = achar(13), tab = achar(9), esc = achar(27)

contains

   subroutine collect_config_robustness(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('messages_are_one_short_line', test_short_messages), &
               new_unittest('nan_boundary_h_does_not_trap', test_nan_boundary_h), &
               new_unittest('control_characters_in_text', test_control_characters), &
               new_unittest('long_strings_in_linear_time', test_long_strings), &
               new_unittest('last_line_of_full_chunks_is_read', test_last_line), &
               new_unittest('memory_splits_lines_like_a_file', test_split_like_file), &
               new_unittest('many_groups_and_keys_bounded', test_many_names)]
   end subroutine collect_config_robustness

   !> Messages quoted input whole and raw: a 5000-character token made a 5000-character
   !> message, and an escape or a newline in an override made it more than one clean line.
   subroutine test_short_messages(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: message

      call load_message('robust_stray.nml', esc//repeat('y', 5000)//nl, no_overrides(), message)
      call check(err, index(message, ":1: stray text outside groups: '<0x1B>yyy") > 0, 'stray text: '//message)
      call check_short(err, message)
      call load_message('robust_key.nml', '&mesh '//repeat('k', 5000)//' = 1 /', no_overrides(), message)
      call check(err, index(message, 'unknown key') > 0, 'long key: '//message)
      call check_short(err, message)
      call load_message('robust_group.nml', '&'//repeat('g', 5000)//' /', no_overrides(), message)
      call check(err, index(message, 'unknown group') > 0, 'long group: '//message)
      call check_short(err, message)
      call load_message('robust_value.nml', "&mesh domain = '"//repeat('d', 250)//tab//"' /", &
                        no_overrides(), message)
      call check_short(err, message)
      call load_message('robust_override.nml', '', words('mesh.levels=1'//nl//'2'), message)
      call check(err, index(message, "override 'mesh.levels=1<0x0A>2'") == 1, 'override: '//message)
      call check_short(err, message)
      call load_message('robust_override_long.nml', '', words('mesh.'//repeat('z', 3000)//'=1'), message)
      call check(err, index(message, "override 'mesh.zzz") == 1, 'long override: '//message)
      call check_short(err, message)
      ! blanks before the dot still name the group; found by a longer fuzz run (seed 2)
      call load_message('robust_override_blanks.nml', '', words('mesh'//repeat(' ', 3000)//'.nokey=1'), message)
      call check(err, index(message, "': &mesh: unknown key 'nokey'") > 0, 'blanks before the dot: '//message)
      call check_short(err, message)
   end subroutine test_short_messages

   !> Load `content` with `overrides`, expecting a bad-input error; its message, or '' if none.
   subroutine load_message(name, content, overrides, message)
      character(len=*), intent(in) :: name, content
      type(string_t), intent(in) :: overrides(:)
      character(len=:), allocatable, intent(out) :: message

      type(config_t) :: cfg
      type(error_t), allocatable :: got

      message = ''
      call load_config(write_case(name, content), overrides, cfg, got)
      if (.not. allocated(got)) return
      if (got%code == exit_bad_input) message = got%message
   end subroutine load_message

   !> No control character and at most a few hundred characters besides the file name.
   subroutine check_short(err, message)
      type(error_t), allocatable, intent(inout) :: err
      character(len=*), intent(in) :: message

      integer :: i

      call check(err, len(message) > 0, 'no bad-input error')
      call check(err, len(message) < 400 + 200, 'message of too many characters')
      do i = 1, len(message)
         call check(err, iachar(message(i:i)) >= 32 .and. iachar(message(i:i)) /= 127, &
                    'control character in the message')
      end do
   end subroutine check_short

   !> The cross rule boundary_h <= coarse_h compared a NaN, which traps in debug builds (SIGFPE
   !> instead of a message); the finiteness check must speak first.
   subroutine test_nan_boundary_h(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'robust_nan_bh.nml', '&mesh boundary_h = nan /', &
                        [character(len=40) :: ':1:', 'boundary_h must be finite'])
      call expect_error(err, 'robust_nan_ch.nml', '&mesh coarse_h = nan, boundary_h = 0.1 /', &
                        [character(len=40) :: ':1:', 'coarse_h must be finite'])
      call expect_error(err, 'robust_nan_bh_override.nml', '', &
                        [character(len=40) :: "override 'mesh.boundary_h=nan'", 'must be finite'], &
                        words('mesh.boundary_h=nan'), in_file=.false.)
   end subroutine test_nan_boundary_h

   !> A newline reached a file name through an override and was accepted; the echo (stored as a
   !> result's input) then held a string broken over two lines and no longer loaded.
   subroutine test_control_characters(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg, again
      type(error_t), allocatable :: got

      call expect_error(err, 'robust_nl_override.nml', '', &
                        [character(len=40) :: "override 'output.file=a<0x0A>b.h5'", 'control character'], &
                        words('output.file=a'//nl//'b.h5'), in_file=.false.)
      call expect_error(err, 'robust_tab_file.nml', "&output file = 'a"//tab//"b.h5' /", &
                        [character(len=40) :: ':1:', '&output', 'control character', "'a<0x09>b.h5'"])
      ! what is accepted must echo to a case that loads back to itself
      call load_config(write_case('robust_echo.nml', ''), words("output.file='a b/c''d.h5'"), cfg, got)
      call check(err, .not. allocated(got), 'a path with a blank and a quote is accepted')
      if (allocated(err)) return
      call load_config_text(config_echo(cfg), trim(cfg%source), no_overrides(), again, got)
      call check(err, .not. allocated(got), 'the echo reloads')
      if (allocated(err)) return
      call check(err, config_echo(again) == config_echo(cfg), 'the echo reloads to the same case')
   end subroutine test_control_characters

   !> Quoted values were built a character at a time, and lines a chunk at a time: quadratic
   !> time, minutes for a megabyte (a binary file given as the case). Now linear: a megabyte
   !> takes milliseconds, so 5 s of CPU time leaves a wide margin even on a loaded machine.
   subroutine test_long_strings(err)
      type(error_t), allocatable, intent(out) :: err

      real :: start, finish
      character(len=:), allocatable :: big

      call cpu_time(start)
      big = repeat('x', 1000000)
      call expect_error(err, 'robust_long_string.nml', "&output file = '"//big//"' /", &
                        [character(len=40) :: ':1:', 'text longer than 256'])
      call expect_error(err, 'robust_long_line.nml', big, &
                        [character(len=40) :: ':1:', 'stray text outside groups'])
      call expect_error(err, 'robust_long_override.nml', '', &
                        [character(len=40) :: "override 'output.file='xxx", 'text longer than 256'], &
                        words("output.file='"//big(1:100000)//"'"), in_file=.false.)
      call cpu_time(finish)
      call check(err, finish - start < 5.0, 'a megabyte of input took more than 5 s')
   end subroutine test_long_strings

   !> A last line without a newline whose length is a multiple of the reader's 256-character
   !> chunk ended in a full chunk and then the end of the file, and was dropped: its values
   !> were silently ignored.
   subroutine test_last_line(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=512) :: line
      character(len=:), allocatable :: message

      line = '&mesh levels = 99 /'
      call load_raw('robust_chunk512.nml', line, message)
      call check(err, index(message, 'robust_chunk512.nml:1: &mesh: levels must be <= 12') > 0, &
                 '512 characters: '//message)
      line = 'levels = 99 /'
      call load_raw('robust_chunk256.nml', '&mesh'//nl//line(1:256), message)
      call check(err, index(message, 'robust_chunk256.nml:2: &mesh: levels must be <= 12') > 0, &
                 '256 characters: '//message)
   end subroutine test_last_line

   !> Write `content` byte for byte (a formatted write would end it with a newline), load it,
   !> and return the error message ('' if it loads).
   subroutine load_raw(name, content, message)
      character(len=*), intent(in) :: name, content
      character(len=:), allocatable, intent(out) :: message

      type(config_t) :: cfg
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path
      integer :: unit

      path = write_case(name, '')
      open (newunit=unit, file=path, access='stream', form='unformatted', status='replace', action='write')
      write (unit) content
      close (unit)
      message = ''
      call load_config(path, no_overrides(), cfg, got)
      if (allocated(got)) message = got%message
   end subroutine load_raw

   !> The run-time library ends a line of a file at a lone CR too; a text in memory (a result's
   !> input) must split the same way, or the same text means different cases.
   subroutine test_split_like_file(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=*), parameter :: text = '! comment'//cr//'&mesh levels = 99 /'//cr//nl
      type(config_t) :: cfg
      type(error_t), allocatable :: got

      call expect_error(err, 'robust_cr.nml', text, [character(len=40) :: ':2:', 'levels must be <= 12'])
      call load_config_text(text, 'robust_cr.nml', no_overrides(), cfg, got)
      call check(err, allocated(got), 'from memory, the line after a lone CR is ignored')
      if (allocated(err)) return
      call check(err, index(got%message, 'robust_cr.nml:2: &mesh: levels must be <= 12') == 1, &
                 'from memory: '//got%message)
   end subroutine test_split_like_file

   !> Repeated groups and keys are found by comparing each name with those before it: a file
   !> of 60 000 groups or of 60 000 keys in one group took minutes (quadratic). No case needs
   !> more than a handful of either, so the parser stops at 100 groups and 200 assignments.
   subroutine test_many_names(err)
      type(error_t), allocatable, intent(out) :: err

      integer, parameter :: n = 60000
      real :: start, finish
      ! fixed-width lines, filled in place: appending would itself be quadratic
      character(len=10*n) :: groups
      character(len=6 + 11*n + 2) :: keys
      integer :: i

      call cpu_time(start)
      keys(1:6) = '&mesh'//nl
      do i = 1, n
         write (groups(10*i - 9:10*i - 1), '("&g",i5.5," /")') i
         groups(10*i:10*i) = nl
         write (keys(6 + 11*i - 10:6 + 11*i - 1), '("k",i5.5," = 1")') i
         keys(6 + 11*i:6 + 11*i) = nl
      end do
      keys(len(keys) - 1:) = '/'//nl
      call expect_error(err, 'robust_groups.nml', groups, &
                        [character(len=40) :: ':101:', 'more than 100 groups'])
      call expect_error(err, 'robust_keys.nml', keys, &
                        [character(len=40) :: ':202: &mesh', 'more than 200 assignments'])
      call cpu_time(finish)
      call check(err, finish - start < 10.0, '60 000 groups or keys took more than 10 s')
   end subroutine test_many_names
end module test_config_robustness
