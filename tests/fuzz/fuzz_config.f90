!> Fuzz targets: the case input, as a namelist file and as `GROUP.KEY=VALUE` overrides. Inputs
!> are mutations of the shipped cases and of the echo of the default configuration (every group
!> and key once), with random assignments of every key to values of every kind, and overrides
!> put together from real and made-up groups, keys and values. `load_config` must either
!> accept, with a configuration whose echo reloads to the identical echo (the echo is what a
!> result file stores as its input), or reject with a bad-input message that starts with the
!> file name or with the override it is about.
module fuzz_config
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t
   use twomem_input_config, only: config_t, string_t, load_config, load_config_text, config_echo
   use fuzz_random, only: rng_t
   use fuzz_mutate, only: word_t, mutate, add_word
   use fuzz_checks, only: message_problem
   use fuzz_harness, only: fuzz_target_t, read_bytes, write_bytes
   implicit none
   private

   public :: namelist_target_t, override_target_t

   !> What both targets draw from: the seeds, the groups and keys the echo lists, values of
   !> every kind, and the namelist's punctuation.
   type :: vocabulary_t
      type(word_t), allocatable :: seeds(:)
      type(word_t), allocatable :: groups(:), keys(:)
      !> key_group(k): index in `groups` of key k
      integer, allocatable :: key_group(:)
      !> key_kind(k): the kind of key k's default value (one of the kind_* below)
      integer, allocatable :: key_kind(:)
      type(word_t), allocatable :: values(:)
      !> values of the right kind (by kind_*), so that many inputs get past conversion
      type(word_t), allocatable :: typed(:, :)
      type(word_t), allocatable :: words(:)
   end type vocabulary_t

   type, extends(fuzz_target_t) :: namelist_target_t
      type(vocabulary_t) :: v
   contains
      procedure :: init => namelist_init
      procedure :: generate => namelist_generate
      procedure :: try => namelist_try
   end type namelist_target_t

   type, extends(fuzz_target_t) :: override_target_t
      type(vocabulary_t) :: v
      !> the valid case file the overrides apply to
      character(len=:), allocatable :: base
   contains
      procedure :: init => override_init
      procedure :: generate => override_generate
      procedure :: try => override_try
   end type override_target_t

   character, parameter :: lf = achar(10), nul = achar(0)
   integer, parameter :: kind_text = 1, kind_int = 2, kind_real = 3, kind_logical = 4

contains

   ! ------------------------------------------------------------------ the vocabulary

   !> Seeds from `source` (the repository: the cases in input/) plus the default echo; groups and keys
   !> read off the echo, so the fuzzer follows the key table without a copy of it.
   subroutine vocabulary_init(v, source)
      type(vocabulary_t), intent(out) :: v
      character(len=*), intent(in) :: source

      type(config_t) :: defaults
      type(error_t), allocatable :: err
      type(string_t), allocatable :: none(:)
      character(len=:), allocatable :: echo, line
      integer :: p, q, i
      character(len=300) :: long_x

      allocate (none(0), v%seeds(0), v%groups(0), v%keys(0), v%key_group(0), v%key_kind(0))
      call load_config_text('', 'default.nml', none, defaults, err)
      if (allocated(err)) error stop 'twomem_fuzz: the empty case does not load'
      echo = config_echo(defaults)
      call add_word(v%seeds, echo)
      call add_word(v%seeds, read_bytes(source//'/input/default.nml'))
      call add_word(v%seeds, read_bytes(source//'/input/paper_p1.nml'))
      call add_word(v%seeds, '&mesh levels = 0, coarse_h = 0.5 /'//lf//"&newton linear = 'direct' /"//lf)
      p = 1
      do while (p <= len(echo))
         q = index(echo(p:), lf)
         line = echo(p:p + q - 2)
         p = p + q
         if (line(1:1) == '&') then
            call add_word(v%groups, line(2:))
         else if (line(1:3) == '   ') then
            call add_word(v%keys, line(4:index(line, ' = ') - 1))
            v%key_group = [v%key_group, size(v%groups)]
            v%key_kind = [v%key_kind, kind_of(line(index(line, ' = ') + 3:))]
         end if
      end do
      if (size(v%groups) /= 7 .or. size(v%keys) < 34) error stop 'twomem_fuzz: cannot read the echo'

      long_x = repeat('x', len(long_x))
      call add_list(v%values, [character(len=40) :: '1', '0', '-1', '2', '3', '12', '13', '1000', &
         '100000', '100001', '2147483647', '2147483648', '-2147483648', '999999999999999999', &
         '99999999999999999999', '+5', '1.0', '0.5', '-0.25', '.5', '1.', '1e-10', '1d-3', &
         '1E+2', '2e-12', '1e999', '-1e999', '1e308', '1e-400', '4.9e-324', '0.0001', '2.0', &
         '2.0000000000000004', 'nan', 'NaN', '-inf', 'inf', 'Infinity', '1e', '.e1', '0x1', &
         '.true.', '.false.', 't', 'f', '.t.', 'TRUE', 'yes', '.tru.', &
         "'disk'", "'square'", "'gmsh'", "'radial'", "'bbbv'", "'none'", "'min'", "'fb'", &
         "'direct'", "'gmres'", "'adaptive'", "'paper'", "'nested'", "'auto'", "'on'", "'off'", &
         "'mg'", "'ilu0'", "'jacobi'", "'fixed'", "'rt0'", "'rt1'", "'global'", "'local'", &
         "' GMSH '", 'disk', 'gmsh', 'FB', "''", '""', "'it''s'", '"a""b"', "'unterminated", &
         '"mixed''', "'a' 'b'", 'out/a.h5', "'out/a.h5'", "'input/meshes/lshape.msh'", &
         "'/dev/null'", '3*1', '1,2', '1 2', '(1)', '&', '/', '!', '=', '.', "'!'", "'/'", &
         "'&mesh'", "'a=b'"])
      call add_word(v%values, "'"//long_x//"'")
      call add_word(v%values, long_x)
      call add_word(v%values, "'"//long_x(1:256)//"'")
      call add_word(v%values, "'"//long_x(1:257)//"'")
      call add_word(v%values, "'"//repeat("''", 200)//"'")
      call add_word(v%values, "'tab"//achar(9)//"'")
      call add_word(v%values, "'nul"//nul//"'")
      call add_word(v%values, "'cr"//achar(13)//"'")
      ! a newline can reach a value only through an override (a file splits at it)
      call add_word(v%values, 'out/a'//lf//'b.h5')
      call add_word(v%values, "'out/a"//lf//"b.h5'")
      call add_word(v%values, char(195)//char(169))

      allocate (v%typed(8, 4))
      call fill(v%typed(:, kind_text), [character(len=12) :: "'disk'", "'gmsh'", "'fb'", &
         "'direct'", "'nested'", "'ilu0'", "'rt0'", "'local'"])
      call fill(v%typed(:, kind_int), [character(len=12) :: '0', '1', '3', '12', '30', &
         '100', '5000', '100000'])
      call fill(v%typed(:, kind_real), [character(len=12) :: '0.5', '1', '0.1', '1e-8', &
         '2.0', '0.25', '-3.5', '1d-3'])
      call fill(v%typed(:, kind_logical), [character(len=12) :: '.true.', '.false.', 't', &
         'f', '.T.', 'false', '.f.', 'TRUE'])

      ! namelist punctuation, group and key spellings, values: the dictionary of mutations
      call add_list(v%words, [character(len=16) :: '&end', '$end', '&END', '/', '//', '=', &
         '==', ',', ',,', '!', '! comment', "'", '"', '*', '(', ')', '(1)', '&', '$', '&/', &
         '/&', '&nosuch', '$mesh', '&Mesh', 'a%b', 'mesh.levels', ' ', '', achar(9), achar(13)])
      call add_word(v%words, nul)
      do i = 1, size(v%groups)
         call add_word(v%words, '&'//v%groups(i)%s)
         call add_word(v%words, '&'//v%groups(i)%s//' /')
      end do
      do i = 1, size(v%keys)
         call add_word(v%words, v%keys(i)%s)
         call add_word(v%words, v%keys(i)%s//' =')
         call add_word(v%words, v%keys(i)%s//'(1)')
      end do
      do i = 1, size(v%values)
         call add_word(v%words, v%values(i)%s)
      end do
   end subroutine vocabulary_init

   !> The kind of a value as the echo writes it.
   pure integer function kind_of(value)
      character(len=*), intent(in) :: value

      if (value(1:1) == "'") then
         kind_of = kind_text
      else if (value(1:1) == '.') then
         kind_of = kind_logical
      else if (scan(value, '.e') > 0) then
         kind_of = kind_real
      else
         kind_of = kind_int
      end if
   end function kind_of

   subroutine fill(words, list)
      type(word_t), intent(inout) :: words(:)
      character(len=*), intent(in) :: list(:)

      integer :: i

      do i = 1, size(words)
         words(i)%s = trim(list(i))
      end do
   end subroutine fill

   !> A value for key k: of its own kind more often than not.
   function value_for(v, rng, k) result(s)
      type(vocabulary_t), intent(in) :: v
      type(rng_t), intent(inout) :: rng
      integer, intent(in) :: k
      character(len=:), allocatable :: s

      if (rng%chance(0.6_dp)) then
         s = any_of(rng, v%typed(:, v%key_kind(k)))
      else
         s = any_of(rng, v%values)
      end if
   end function value_for

   subroutine add_list(words, list)
      type(word_t), allocatable, intent(inout) :: words(:)
      character(len=*), intent(in) :: list(:)

      integer :: i

      if (.not. allocated(words)) allocate (words(0))
      do i = 1, size(list)
         call add_word(words, trim(list(i)))
      end do
   end subroutine add_list

   function any_of(rng, words) result(s)
      type(rng_t), intent(inout) :: rng
      type(word_t), intent(in) :: words(:)
      character(len=:), allocatable :: s

      integer :: i

      ! the index first: gfortran may evaluate a subscript twice (for the length and for the
      ! text), and each evaluation here draws a new number
      i = rng%between(1, size(words))
      s = words(i)%s
   end function any_of

   !> '' if the echo of `cfg` reloads (as the `input` attribute of a result does) to the same
   !> echo, else what went wrong.
   function round_trip_problem(cfg, source) result(problem)
      type(config_t), intent(in) :: cfg
      character(len=*), intent(in) :: source
      character(len=:), allocatable :: problem

      type(config_t) :: again
      type(error_t), allocatable :: err
      type(string_t), allocatable :: none(:)
      character(len=:), allocatable :: echo

      allocate (none(0))
      problem = ''
      echo = config_echo(cfg)
      call load_config_text(echo, source, none, again, err)
      if (allocated(err)) then
         problem = 'the echo of an accepted case does not reload: '//err%message
      else if (config_echo(again) /= echo) then
         problem = 'the echo of an accepted case reloads to a different case'
      end if
   end function round_trip_problem

   !> '' if `text` loaded from memory gives what loading it from the file `path` gave: the same
   !> echo, or the same error message.
   function same_answer_problem(text, path, from_file, file_err) result(problem)
      character(len=*), intent(in) :: text, path
      type(config_t), intent(in) :: from_file
      type(error_t), allocatable, intent(in) :: file_err
      character(len=:), allocatable :: problem

      type(config_t) :: cfg
      type(error_t), allocatable :: err
      type(string_t), allocatable :: none(:)

      allocate (none(0))
      problem = ''
      call load_config_text(text, path, none, cfg, err)
      if (allocated(err) .neqv. allocated(file_err)) then
         problem = 'the file and the same text in memory load differently (one is rejected)'
      else if (allocated(err)) then
         if (err%message /= file_err%message) &
            problem = 'the file and the same text in memory are rejected with different '// &
                      'messages; from memory: '//err%message
      else if (config_echo(cfg) /= config_echo(from_file)) then
         problem = 'the file and the same text in memory load to different cases'
      end if
   end function same_answer_problem

   ! ------------------------------------------------------------------ namelist files

   subroutine namelist_init(self, source)
      class(namelist_target_t), intent(inout) :: self
      character(len=*), intent(in) :: source

      self%name = 'namelist'
      self%extension = '.nml'
      call vocabulary_init(self%v, source)
   end subroutine namelist_init

   !> A seed, sometimes with a random assignment (or a group opened or closed) on a line of its
   !> own, then byte, token and line mutations.
   subroutine namelist_generate(self, rng, text)
      class(namelist_target_t), intent(in) :: self
      type(rng_t), intent(inout) :: rng
      character(len=:), allocatable, intent(out) :: text

      character(len=:), allocatable :: line
      integer :: p, k

      text = any_of(rng, self%v%seeds)
      if (rng%chance(0.4_dp)) then
         select case (rng%below(4))
         case (0)
            line = '&'//any_of(rng, self%v%groups)
         case (1)
            line = '/'
         case default
            k = rng%between(1, size(self%v%keys))
            line = self%v%keys(k)%s//' = '//value_for(self%v, rng, k)
         end select
         p = rng%between(1, len(text) + 1)
         do while (p > 1)
            if (text(p - 1:p - 1) == lf) exit
            p = p - 1
         end do
         text = text(1:p - 1)//line//lf//text(p:)
      end if
      if (rng%chance(0.85_dp)) call mutate(text, rng, self%v%words)
   end subroutine namelist_generate

   subroutine namelist_try(self, path, text, accepted, problem, message)
      class(namelist_target_t), intent(in) :: self
      character(len=*), intent(in) :: path, text
      logical, intent(out) :: accepted
      character(len=:), allocatable, intent(out) :: problem, message

      type(config_t) :: cfg
      type(error_t), allocatable :: err
      type(string_t), allocatable :: none(:)

      allocate (none(0))
      call load_config(path, none, cfg, err)
      accepted = .not. allocated(err)
      if (accepted) then
         problem = round_trip_problem(cfg, path)
      else
         problem = message_problem(err, path)
         if (allocated(err%message)) message = err%message
      end if
      ! the same text from memory (as a result file's input is reloaded) must give the same
      ! answer: a file reader that drops or splits a line differently would show here
      if (len(problem) == 0) problem = same_answer_problem(text, path, cfg, err)
   end subroutine namelist_try

   ! ------------------------------------------------------------------ overrides

   !> The overrides apply to input/default.nml, copied to the scratch directory `tmp`.
   subroutine override_init(self, source, tmp)
      class(override_target_t), intent(inout) :: self
      character(len=*), intent(in) :: source, tmp

      self%name = 'override'
      self%extension = '.txt'
      call vocabulary_init(self%v, source)
      self%base = tmp//'/fuzz-override-base.nml'
      call write_bytes(self%base, read_bytes(source//'/input/default.nml'))
   end subroutine override_init

   !> One to three overrides, NUL-separated (NUL cannot occur in a command-line word): mostly
   !> real groups and keys with values of any kind, some with mutations on top.
   subroutine override_generate(self, rng, text)
      class(override_target_t), intent(in) :: self
      type(rng_t), intent(inout) :: rng
      character(len=:), allocatable, intent(out) :: text

      character(len=:), allocatable :: one, group, key
      integer :: i, n, g, k

      text = ''
      n = rng%between(1, 3)
      do i = 1, n
         k = rng%between(1, size(self%v%keys))
         g = self%v%key_group(k)
         group = self%v%groups(g)%s
         key = self%v%keys(k)%s
         if (rng%chance(0.1_dp)) group = any_of(rng, self%v%words)
         if (rng%chance(0.1_dp)) key = any_of(rng, self%v%keys)
         if (rng%chance(0.05_dp)) key = any_of(rng, self%v%words)
         if (rng%chance(0.3_dp)) group = upper(group)
         one = group//'.'//key//'='//value_for(self%v, rng, k)
         if (rng%chance(0.05_dp)) one = group//key//'='//any_of(rng, self%v%values)
         if (rng%chance(0.05_dp)) one = group//'.'//key//any_of(rng, self%v%values)
         if (rng%chance(0.05_dp)) one = ' '//one//' '
         if (rng%chance(0.4_dp)) call mutate(one, rng, self%v%words)
         if (i > 1) text = text//nul
         text = text//one
      end do
   end subroutine override_generate

   pure function upper(s) result(u)
      character(len=*), intent(in) :: s
      character(len=len(s)) :: u

      integer :: i

      u = s
      do i = 1, len(s)
         if (s(i:i) >= 'a' .and. s(i:i) <= 'z') u(i:i) = achar(iachar(s(i:i)) - 32)
      end do
   end function upper

   subroutine override_try(self, path, text, accepted, problem, message)
      class(override_target_t), intent(in) :: self
      character(len=*), intent(in) :: path, text
      logical, intent(out) :: accepted
      character(len=:), allocatable, intent(out) :: problem, message

      type(config_t) :: cfg
      type(error_t), allocatable :: err
      type(string_t), allocatable :: overrides(:)
      integer :: p, q, n

      ! split at the NULs
      n = 1
      do p = 1, len(text)
         if (text(p:p) == nul) n = n + 1
      end do
      allocate (overrides(n))
      p = 1
      do n = 1, size(overrides)
         q = index(text(p:), nul)
         if (q == 0) then
            overrides(n)%s = text(p:)
         else
            overrides(n)%s = text(p:p + q - 2)
            p = p + q
         end if
      end do
      call load_config(self%base, overrides, cfg, err)
      accepted = .not. allocated(err)
      if (accepted) then
         problem = round_trip_problem(cfg, self%base)
      else
         problem = message_problem(err, self%base, "override '")
         if (allocated(err%message)) message = err%message
      end if
   end subroutine override_try
end module fuzz_config
