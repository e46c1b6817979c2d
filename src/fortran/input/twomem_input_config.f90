!> Loading the case (`twomem_input_case`'s types): a case file plus `GROUP.KEY=VALUE` overrides,
!> validated (`twomem_input_rules`), and echoed back as namelist text that reloads to the
!> identical configuration (it heads every run and is stored in the result file). Values are
!> only read and checked here; turning them into meshes and solvers is for their constructors.
!> Text values longer than `config_len` are rejected, never truncated.
module twomem_input_config
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, prefix_error, exit_bad_input, excerpt
   use twomem_input_namelist, only: string_t, nml_group_t, read_lines, split_lines, &
      parse_namelist, line_where
   use twomem_input_values, only: scan_integer, scan_real, scan_logical, unquote, format_real, &
      quote
   use twomem_base_text, only: int_text, to_lower
   use twomem_input_case, only: config_t, mesh_config_t, problem_config_t, newton_config_t, gmres_config_t, &
                                estimate_config_t, output_config_t, adapt_config_t, config_len
   use twomem_input_keys, only: keys, n_keys, n_groups, group_names, find_group, find_key, group_list, key_list, &
      type_word, type_path, type_real, type_int, type_logical, type_load, &
      k_domain, k_mesh_file, k_coarse_h, k_levels, k_boundary_h, k_mu1, k_mu2, k_f1, k_f2, k_g, k_exact, &
      k_f1_file, k_f2_file, k_cfun, k_linear, k_newton_max_it, k_tol, k_gamma_lin, k_initial, k_line_search, &
      k_fb_finish, k_restart, k_gmres_max_it, k_rtol, k_precond, k_forcing, k_gamma_alg, k_enabled, k_every, &
      k_flux, k_alg_levels, k_criteria, k_checks, k_bound, k_output_file, k_fields, k_estimators, k_history, k_xdmf, &
      k_adapt_tol, k_theta, k_max_steps, k_max_vertices
   use twomem_input_options, only: kind_of_word, word_of_kind
   use twomem_input_rules, only: validate
   implicit none
   private

   public :: config_t, mesh_config_t, problem_config_t, newton_config_t, gmres_config_t
   public :: estimate_config_t, output_config_t, adapt_config_t, string_t, config_len
   public :: load_config, load_config_text, config_echo

contains

   !> Read the case file `path`, apply `overrides` (each `GROUP.KEY=VALUE`) in order, validate,
   !> and resolve the default output file. Every failure is bad input (code 2) with a one-line
   !> message naming the file and line, or the override, and the group and key.
   subroutine load_config(path, overrides, cfg, err)
      character(len=*), intent(in) :: path
      type(string_t), intent(in) :: overrides(:)
      type(config_t), intent(out) :: cfg
      type(error_t), allocatable, intent(out) :: err

      type(string_t), allocatable :: lines(:)

      call read_lines(path, lines, err)
      if (allocated(err)) return
      call load_lines(lines, path, overrides, cfg, err)
   end subroutine load_config

   !> As `load_config`, for namelist text held in memory (lines separated by newlines), e.g. the
   !> `input` attribute of a result file; `source` stands for the file name in messages and
   !> gives the case name.
   subroutine load_config_text(text, source, overrides, cfg, err)
      character(len=*), intent(in) :: text
      character(len=*), intent(in) :: source
      type(string_t), intent(in) :: overrides(:)
      type(config_t), intent(out) :: cfg
      type(error_t), allocatable, intent(out) :: err

      type(string_t), allocatable :: lines(:)

      call split_lines(text, lines)
      call load_lines(lines, source, overrides, cfg, err)
   end subroutine load_config_text

   subroutine load_lines(lines, path, overrides, cfg, err)
      type(string_t), intent(in) :: lines(:)
      character(len=*), intent(in) :: path
      type(string_t), intent(in) :: overrides(:)
      type(config_t), intent(inout) :: cfg
      type(error_t), allocatable, intent(out) :: err

      type(nml_group_t), allocatable :: groups(:)
      ! where each key's value came from, for validation messages: 'file:line', the override,
      ! or just the file for a default; and each word as given, which validation names when it
      ! is none of its key's words
      type(string_t) :: origin(n_keys), given(n_keys)
      integer :: ig, ia, gid, id, i

      if (len(path) > config_len) then
         call make_error(err, exit_bad_input, path, 'path longer than '//int_text(config_len)//' characters')
         return
      end if
      cfg%source = path
      cfg%case_name = case_name_of(path)
      do i = 1, n_keys
         origin(i)%s = path
      end do

      call parse_namelist(lines, path, groups, err)
      if (allocated(err)) return
      do ig = 1, size(groups)
         gid = find_group(groups(ig)%name)
         if (gid == 0) then
            call make_error(err, exit_bad_input, line_where(path, groups(ig)%line)//': &'//excerpt(groups(ig)%name), &
                            'unknown group (valid groups: '//group_list()//')')
            return
         end if
         do ia = 1, groups(ig)%n
            associate (a => groups(ig)%assignments(ia))
               id = find_key(gid, a%key)
               if (id == 0) then
                  call make_error(err, exit_bad_input, line_where(path, a%line)//': &'//groups(ig)%name &
                                  //': '//excerpt(a%key), 'unknown key (valid keys: '//key_list(gid)//')')
                  return
               end if
               call set_value(cfg, id, a%value, a%quoted, given(id), err)
               if (allocated(err)) then
                  call prefix_error(err, line_where(path, a%line)//': &'//groups(ig)%name//': '//a%key)
                  return
               end if
               origin(id)%s = line_where(path, a%line)
            end associate
         end do
      end do

      do i = 1, size(overrides)
         call apply_override(cfg, overrides(i)%s, id, given, err)
         if (allocated(err)) return
         origin(id)%s = "override '"//excerpt(overrides(i)%s)//"'"
      end do

      call validate(cfg, origin, given, err)
      if (allocated(err)) return
      if (len_trim(cfg%output%file) == 0) cfg%output%file = 'results/'//trim(cfg%case_name)//'.h5'
   end subroutine load_lines

   !> One `GROUP.KEY=VALUE`; the value uses namelist syntax but text may go unquoted, so
   !> `output.file=out/a.h5` works from a shell. Returns the key's row in `id`; a word goes to
   !> given(id) too.
   subroutine apply_override(cfg, text, id, given, err)
      type(config_t), intent(inout) :: cfg
      character(len=*), intent(in) :: text
      integer, intent(out) :: id
      type(string_t), intent(inout) :: given(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: where, name, group, key, raw, value, what
      integer :: eq, dot, gid
      logical :: quoted

      id = 0
      where = "override '"//excerpt(text)//"'"
      eq = index(text, '=')
      if (eq == 0) then
         call make_error(err, exit_bad_input, where, "expected GROUP.KEY=VALUE (no '=')")
         return
      end if
      name = to_lower(trim(adjustl(text(1:eq - 1))))
      dot = index(name, '.')
      if (dot == 0) then
         call make_error(err, exit_bad_input, where, "expected GROUP.KEY=VALUE (no '.' in the key)")
         return
      end if
      group = name(1:dot - 1)
      key = name(dot + 1:)
      gid = find_group(group)
      if (gid == 0) then
         call make_error(err, exit_bad_input, where, "unknown group '"//excerpt(group)//"' (valid groups: " &
                         //group_list()//')')
         return
      end if
      id = find_key(gid, key)
      if (id == 0) then
         ! trim: blanks before the dot still name the group (== ignores trailing blanks)
         call make_error(err, exit_bad_input, where, '&'//trim(group)//": unknown key '"//excerpt(key) &
                         //"' (valid keys: "//key_list(gid)//')')
         return
      end if
      raw = trim(adjustl(text(eq + 1:)))
      if (len(raw) == 0) then
         call make_error(err, exit_bad_input, where, "missing value after '=' (write '' for empty text)")
         return
      end if
      call unquote(raw, value, quoted, what)
      if (allocated(what)) then
         call make_error(err, exit_bad_input, where, what)
         return
      end if
      call set_value(cfg, id, value, quoted, given(id), err)
      if (allocated(err)) call prefix_error(err, where)
   end subroutine apply_override

   !> Convert `value` to the type of key `id` and store it. A word is stored as its kind,
   !> lower-cased first (0 when it is none of the key's words; `given` keeps its text for the
   !> message), file names verbatim. Range and word checks wait for `validate`, so an override
   !> can still fix a bad file value; only what cannot be converted fails here.
   subroutine set_value(cfg, id, value, quoted, given, err)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id
      character(len=*), intent(in) :: value
      logical, intent(in) :: quoted
      type(string_t), intent(inout) :: given
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: what
      real(dp) :: x
      integer :: n
      logical :: b

      select case (keys(id)%type)
      case (type_word, type_path)
         if (len(value) > config_len) then
            what = 'text longer than '//int_text(config_len)//' characters'
         else if (has_control_character(value)) then
            ! a newline would break the echo, which must reload as a case file
            what = 'text with a control character, got '//quote(excerpt(value))
         else if (keys(id)%type == type_word) then
            given%s = to_lower(trim(adjustl(value)))
            call store_kind(cfg, id, kind_of_word(id, given%s))
         else
            call store_text(cfg, id, value)
         end if
      case (type_real)
         if (quoted) then
            what = 'expected a real number, got the string '//quote(excerpt(value))
         else
            call scan_real(value, x, what)
            if (.not. allocated(what)) call store_real(cfg, id, x)
         end if
      case (type_int)
         if (quoted) then
            what = 'expected an integer, got the string '//quote(excerpt(value))
         else
            call scan_integer(value, n, what)
            if (.not. allocated(what)) call store_int(cfg, id, n)
         end if
      case (type_load)
         ! a number stays a number (bit-for-bit the same run as before formulas existed), quoted
         ! or not; anything else is kept as a formula and parsed by `validate`
         call scan_real(value, x, what)
         if (len_trim(value) == 0) then
            what = 'expected a number or a formula, got an empty string'
         else if (.not. allocated(what)) then
            call store_real(cfg, id, x)
            call store_text(cfg, id, '')
         else if (index(what, 'out of range') > 0) then
            ! a real literal that overflows is a bad number, not a formula: keep scan_real's message
            continue
         else if (len(value) > config_len) then
            what = 'formula longer than '//int_text(config_len)//' characters'
         else if (has_control_character(value)) then
            what = 'formula with a control character, got '//quote(excerpt(value))
         else
            deallocate (what)
            call store_text(cfg, id, trim(adjustl(value)))
         end if
      case (type_logical)
         if (quoted) then
            what = 'expected a logical (.true. or .false.), got the string '//quote(excerpt(value))
         else
            call scan_logical(value, b, what)
            if (.not. allocated(what)) call store_logical(cfg, id, b)
         end if
      end select
      if (allocated(what)) call make_error(err, exit_bad_input, '', what)
   end subroutine set_value

   subroutine store_text(cfg, id, s)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id
      character(len=*), intent(in) :: s

      select case (id)
      case (k_mesh_file); cfg%mesh%file = s
      case (k_output_file); cfg%output%file = s
      case (k_f1); cfg%problem%f1_formula = s
      case (k_f2); cfg%problem%f2_formula = s
      case (k_f1_file); cfg%problem%f1_file = s
      case (k_f2_file); cfg%problem%f2_file = s
      end select
   end subroutine store_text

   subroutine store_kind(cfg, id, kind)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id, kind

      select case (id)
      case (k_domain); cfg%mesh%domain = kind
      case (k_exact); cfg%problem%exact = kind
      case (k_cfun); cfg%newton%cfun = kind
      case (k_linear); cfg%newton%linear = kind
      case (k_initial); cfg%newton%initial = kind
      case (k_line_search); cfg%newton%line_search = kind
      case (k_fb_finish); cfg%newton%fb_finish = kind
      case (k_precond); cfg%gmres%precond = kind
      case (k_forcing); cfg%gmres%forcing = kind
      case (k_flux); cfg%estimate%flux = kind
      case (k_criteria); cfg%estimate%criteria = kind
      case (k_checks); cfg%estimate%checks = kind
      case (k_bound); cfg%estimate%bound = kind
      end select
   end subroutine store_kind

   !> The kind of word key `id` (0 for another key).
   pure integer function kind_value(cfg, id) result(kind)
      type(config_t), intent(in) :: cfg
      integer, intent(in) :: id

      select case (id)
      case (k_domain); kind = cfg%mesh%domain
      case (k_exact); kind = cfg%problem%exact
      case (k_cfun); kind = cfg%newton%cfun
      case (k_linear); kind = cfg%newton%linear
      case (k_initial); kind = cfg%newton%initial
      case (k_line_search); kind = cfg%newton%line_search
      case (k_fb_finish); kind = cfg%newton%fb_finish
      case (k_precond); kind = cfg%gmres%precond
      case (k_forcing); kind = cfg%gmres%forcing
      case (k_flux); kind = cfg%estimate%flux
      case (k_criteria); kind = cfg%estimate%criteria
      case (k_checks); kind = cfg%estimate%checks
      case (k_bound); kind = cfg%estimate%bound
      case default; kind = 0
      end select
   end function kind_value

   subroutine store_real(cfg, id, x)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id
      real(dp), intent(in) :: x

      select case (id)
      case (k_coarse_h); cfg%mesh%coarse_h = x
      case (k_boundary_h); cfg%mesh%boundary_h = x
      case (k_mu1); cfg%problem%mu1 = x
      case (k_mu2); cfg%problem%mu2 = x
      case (k_f1); cfg%problem%f1 = x
      case (k_f2); cfg%problem%f2 = x
      case (k_g); cfg%problem%g = x
      case (k_tol); cfg%newton%tol = x
      case (k_gamma_lin); cfg%newton%gamma_lin = x
      case (k_rtol); cfg%gmres%rtol = x
      case (k_gamma_alg); cfg%estimate%gamma_alg = x
      case (k_adapt_tol); cfg%adapt%tol = x
      case (k_theta); cfg%adapt%theta = x
      end select
   end subroutine store_real

   subroutine store_int(cfg, id, n)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id, n

      select case (id)
      case (k_levels); cfg%mesh%levels = n
      case (k_newton_max_it); cfg%newton%max_it = n
      case (k_restart); cfg%gmres%restart = n
      case (k_gmres_max_it); cfg%gmres%max_it = n
      case (k_every); cfg%estimate%every = n
      case (k_alg_levels); cfg%estimate%alg_levels = n
      case (k_max_steps); cfg%adapt%max_steps = n
      case (k_max_vertices); cfg%adapt%max_vertices = n
      end select
   end subroutine store_int

   subroutine store_logical(cfg, id, b)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id
      logical, intent(in) :: b

      select case (id)
      case (k_enabled); cfg%estimate%enabled = b
      case (k_fields); cfg%output%fields = b
      case (k_estimators); cfg%output%estimators = b
      case (k_history); cfg%output%history = b
      case (k_xdmf); cfg%output%xdmf = b
      end select
   end subroutine store_logical

   !> The configuration as namelist text: every group, every key, one per line, reals in the
   !> shortest form that reads back bit-identically. `load_config` of this text gives `cfg` again.
   function config_echo(cfg) result(text)
      type(config_t), intent(in) :: cfg
      character(len=:), allocatable :: text

      character, parameter :: nl = new_line('a')
      integer :: gid, id

      text = '! twomem input: case '//quote(trim(cfg%case_name))//' from '//quote(trim(cfg%source))//nl
      do gid = 1, n_groups
         text = text//'&'//trim(group_names(gid))//nl
         do id = 1, n_keys
            if (keys(id)%group /= gid) cycle
            text = text//'   '//trim(keys(id)%name)//' = '//value_text(cfg, id)//nl
         end do
         text = text//'/'//nl
      end do
   end function config_echo

   !> The namelist literal of key `id`; a word's from its kind, by the table that read it.
   function value_text(cfg, id) result(s)
      type(config_t), intent(in) :: cfg
      integer, intent(in) :: id
      character(len=:), allocatable :: s

      if (keys(id)%type == type_word) then
         s = quote(word_of_kind(id, kind_value(cfg, id)))
         return
      end if
      select case (id)
      case (k_mesh_file); s = quote(trim(cfg%mesh%file))
      case (k_coarse_h); s = format_real(cfg%mesh%coarse_h)
      case (k_boundary_h); s = format_real(cfg%mesh%boundary_h)
      case (k_levels); s = int_text(cfg%mesh%levels)
      case (k_mu1); s = format_real(cfg%problem%mu1)
      case (k_mu2); s = format_real(cfg%problem%mu2)
      case (k_f1); s = load_text(cfg%problem%f1, cfg%problem%f1_formula)
      case (k_f2); s = load_text(cfg%problem%f2, cfg%problem%f2_formula)
      case (k_f1_file); s = quote(trim(cfg%problem%f1_file))
      case (k_f2_file); s = quote(trim(cfg%problem%f2_file))
      case (k_g); s = format_real(cfg%problem%g)
      case (k_newton_max_it); s = int_text(cfg%newton%max_it)
      case (k_tol); s = format_real(cfg%newton%tol)
      case (k_gamma_lin); s = format_real(cfg%newton%gamma_lin)
      case (k_restart); s = int_text(cfg%gmres%restart)
      case (k_gmres_max_it); s = int_text(cfg%gmres%max_it)
      case (k_rtol); s = format_real(cfg%gmres%rtol)
      case (k_every); s = int_text(cfg%estimate%every)
      case (k_alg_levels); s = int_text(cfg%estimate%alg_levels)
      case (k_gamma_alg); s = format_real(cfg%estimate%gamma_alg)
      case (k_enabled); s = logical_text(cfg%estimate%enabled)
      case (k_output_file); s = quote(trim(cfg%output%file))
      case (k_fields); s = logical_text(cfg%output%fields)
      case (k_estimators); s = logical_text(cfg%output%estimators)
      case (k_history); s = logical_text(cfg%output%history)
      case (k_xdmf); s = logical_text(cfg%output%xdmf)
      case (k_adapt_tol); s = format_real(cfg%adapt%tol)
      case (k_theta); s = format_real(cfg%adapt%theta)
      case (k_max_steps); s = int_text(cfg%adapt%max_steps)
      case (k_max_vertices); s = int_text(cfg%adapt%max_vertices)
      case default; s = ''
      end select
   end function value_text

   function load_text(x, formula) result(s)
      real(dp), intent(in) :: x
      character(len=*), intent(in) :: formula
      character(len=:), allocatable :: s

      if (len_trim(formula) > 0) then
         s = quote(trim(formula))
      else
         s = format_real(x)
      end if
   end function load_text

   pure function logical_text(b) result(s)
      logical, intent(in) :: b
      character(len=:), allocatable :: s

      if (b) then
         s = '.true.'
      else
         s = '.false.'
      end if
   end function logical_text

   !> `input/default.nml` -> `default`: no directory, no last extension.
   pure function case_name_of(path) result(name)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: name

      integer :: slash, dot

      slash = scan(path, '/\', back=.true.)
      name = path(slash + 1:)
      dot = index(name, '.', back=.true.)
      if (dot > 1) name = name(1:dot - 1)
   end function case_name_of

   !> Bytes 0-31 and 127, which no word or file name of a case may contain.
   pure logical function has_control_character(s)
      character(len=*), intent(in) :: s

      integer :: i

      has_control_character = .false.
      do i = 1, len(s)
         if (iachar(s(i:i)) < 32 .or. iachar(s(i:i)) == 127) has_control_character = .true.
      end do
   end function has_control_character
end module twomem_input_config
