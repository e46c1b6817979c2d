!> The case description: one derived type per namelist group, with the documented defaults as
!> default initialization, loaded from a case file plus `GROUP.KEY=VALUE` overrides, validated,
!> and echoed back as namelist text that reloads to the identical configuration (it heads every
!> run and is stored in the result file). Values are only read and checked here; turning them
!> into meshes and solvers is for their constructors. Text components have the fixed length
!> `config_len` so that defaults can be default initialization; longer values are rejected.
module twomem_input_config
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, prefix_error, exit_bad_input, excerpt
   use twomem_input_namelist, only: string_t, nml_group_t, read_lines, split_lines, &
      parse_namelist, line_where
   use twomem_input_values, only: scan_integer, scan_real, scan_logical, unquote, format_real, &
      quote
   use twomem_input_formula, only: formula_t
   use twomem_input_formula_parser, only: parse_formula
   use twomem_base_text, only: int_text, to_lower
   implicit none
   private

   public :: config_t, mesh_config_t, problem_config_t, newton_config_t, gmres_config_t
   public :: estimate_config_t, output_config_t, string_t, config_len
   public :: load_config, load_config_text, config_echo

   !> length of every text component (words and file names)
   integer, parameter :: config_len = 256

   type :: mesh_config_t
      character(len=config_len) :: domain = 'disk'
      character(len=config_len) :: file = ''
      real(dp) :: coarse_h = 0.25_dp
      integer :: levels = 4
      !> boundary vertex spacing of the coarse disk; 0 = automatic (from the finest level)
      real(dp) :: boundary_h = 0.0_dp
   end type mesh_config_t

   type :: problem_config_t
      real(dp) :: mu1 = 1.0_dp
      real(dp) :: mu2 = 1.0_dp
      !> the loads when they are numbers (f1_formula, f2_formula empty)
      real(dp) :: f1 = -0.25_dp
      real(dp) :: f2 = 0.25_dp
      real(dp) :: g = 0.05_dp
      character(len=config_len) :: exact = 'none'
      !> the loads as formulas of x, y, r (`twomem_input_formula`); '' when they are numbers
      character(len=config_len) :: f1_formula = ''
      character(len=config_len) :: f2_formula = ''
      !> nodal loads from HDF5, 'FILE:DATASET'; '' when not used
      character(len=config_len) :: f1_file = ''
      character(len=config_len) :: f2_file = ''
   end type problem_config_t

   type :: newton_config_t
      character(len=config_len) :: cfun = 'min'
      character(len=config_len) :: linear = 'adaptive'
      integer :: max_it = 100
      real(dp) :: tol = 1.0e-10_dp
      real(dp) :: gamma_lin = 0.3_dp
      !> 'paper': (u1, u2, λ) = (g, 0, 0); 'nested': solve on each coarser level first
      character(len=config_len) :: initial = 'nested'
      !> 'auto' (on for fb, off for min), 'on', 'off'
      character(len=config_len) :: line_search = 'auto'
      !> 'active_set': Fischer–Burmeister finishes with Newton-min steps once its contact set
      !> settles; 'none': FB throughout (the paper's method)
      character(len=config_len) :: fb_finish = 'active_set'
   end type newton_config_t

   type :: gmres_config_t
      integer :: restart = 30
      integer :: max_it = 5000
      real(dp) :: rtol = 1.0e-10_dp
      !> 'mg' (block elimination, one multigrid V-cycle per SPD block), 'ilu0', 'jacobi', 'none'
      character(len=config_len) :: precond = 'mg'
      !> 'paper': stop when the relative algebraic residual ≤ the relative linearization
      !> residual (the paper's inexact method); 'fixed': at gmres.rtol
      character(len=config_len) :: forcing = 'paper'
   end type gmres_config_t

   type :: estimate_config_t
      real(dp) :: gamma_alg = 0.3_dp
      logical :: enabled = .true.
      !> ν: estimators and history rows every ν GMRES iterations; 0 = automatic (3 with the
      !> multigrid preconditioner, which needs a handful of iterations per Newton step, and
      !> the paper's 10 otherwise)
      integer :: every = 0
      !> flux reconstruction space: 'rt1' (the paper) or 'rt0'
      character(len=config_len) :: flux = 'rt1'
      !> how many of the finest meshes the multilevel algebraic flux uses (the paper: 3)
      integer :: alg_levels = 3
      !> adaptive stopping: 'global' (paper eq. (63)) or 'local' (eq. (64), implies the global)
      character(len=config_len) :: criteria = 'global'
   end type estimate_config_t

   type :: output_config_t
      !> '' in the input means `results/<case>.h5`; resolved by `load_config`
      character(len=config_len) :: file = ''
      logical :: fields = .true.
      logical :: estimators = .true.
      logical :: history = .true.
      logical :: xdmf = .true.
   end type output_config_t

   type :: config_t
      !> base name of the case file without directory and extension
      character(len=config_len) :: case_name = ''
      !> path of the case file as given
      character(len=config_len) :: source = ''
      type(mesh_config_t) :: mesh
      type(problem_config_t) :: problem
      type(newton_config_t) :: newton
      type(gmres_config_t) :: gmres
      type(estimate_config_t) :: estimate
      type(output_config_t) :: output
   end type config_t

   ! The key table: one row per key, in the order of the documentation and of the echo.
   integer, parameter :: n_groups = 6, n_keys = 37
   character(len=*), parameter :: group_names(n_groups) = [character(len=8) :: &
      'mesh', 'problem', 'newton', 'gmres', 'estimate', 'output']
   !> kind_load: a real number, or a formula (quoted in a file; a bare override that is not a
   !> number is a formula too)
   integer, parameter :: kind_word = 1, kind_path = 2, kind_real = 3, kind_int = 4, kind_logical = 5, &
      kind_load = 6
   integer, parameter :: k_domain = 1, k_mesh_file = 2, k_coarse_h = 3, k_levels = 4, &
      k_mu1 = 5, k_mu2 = 6, k_f1 = 7, k_f2 = 8, k_g = 9, k_exact = 10, &
      k_cfun = 11, k_linear = 12, k_newton_max_it = 13, k_tol = 14, k_gamma_lin = 15, &
      k_restart = 16, k_gmres_max_it = 17, k_rtol = 18, k_precond = 19, &
      k_gamma_alg = 20, k_enabled = 21, &
      k_output_file = 22, k_fields = 23, k_estimators = 24, k_history = 25, k_xdmf = 26, &
      k_boundary_h = 27, k_initial = 28, k_line_search = 29, k_forcing = 30, k_every = 31, &
      k_flux = 32, k_alg_levels = 33, k_criteria = 34, k_f1_file = 35, k_f2_file = 36, k_fb_finish = 37
   integer, parameter :: key_group(n_keys) = [1, 1, 1, 1, 2, 2, 2, 2, 2, 2, 3, 3, 3, 3, 3, &
                                              4, 4, 4, 4, 5, 5, 6, 6, 6, 6, 6, 1, 3, 3, 4, 5, 5, 5, 5, &
                                              2, 2, 3]
   character(len=*), parameter :: key_names(n_keys) = [character(len=12) :: &
      'domain', 'file', 'coarse_h', 'levels', &
      'mu1', 'mu2', 'f1', 'f2', 'g', 'exact', &
      'cfun', 'linear', 'max_it', 'tol', 'gamma_lin', &
      'restart', 'max_it', 'rtol', 'precond', &
      'gamma_alg', 'enabled', &
      'file', 'fields', 'estimators', 'history', 'xdmf', 'boundary_h', &
      'initial', 'line_search', 'forcing', 'every', 'flux', 'alg_levels', 'criteria', 'f1_file', 'f2_file', &
      'fb_finish']
   integer, parameter :: key_kinds(n_keys) = [kind_word, kind_path, kind_real, kind_int, &
      kind_real, kind_real, kind_load, kind_load, kind_real, kind_word, &
      kind_word, kind_word, kind_int, kind_real, kind_real, &
      kind_int, kind_int, kind_real, kind_word, &
      kind_real, kind_logical, &
      kind_path, kind_logical, kind_logical, kind_logical, kind_logical, kind_real, &
      kind_word, kind_word, kind_word, kind_int, kind_word, kind_int, kind_word, kind_path, kind_path, &
      kind_word]

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
      ! or just the file for a default
      type(string_t) :: origin(n_keys)
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
               call set_value(cfg, id, a%value, a%quoted, err)
               if (allocated(err)) then
                  call prefix_error(err, line_where(path, a%line)//': &'//groups(ig)%name//': '//a%key)
                  return
               end if
               origin(id)%s = line_where(path, a%line)
            end associate
         end do
      end do

      do i = 1, size(overrides)
         call apply_override(cfg, overrides(i)%s, id, err)
         if (allocated(err)) return
         origin(id)%s = "override '"//excerpt(overrides(i)%s)//"'"
      end do

      call validate(cfg, origin, err)
      if (allocated(err)) return
      if (len_trim(cfg%output%file) == 0) cfg%output%file = 'results/'//trim(cfg%case_name)//'.h5'
   end subroutine load_lines

   !> One `GROUP.KEY=VALUE`; the value uses namelist syntax but text may go unquoted, so
   !> `output.file=out/a.h5` works from a shell. Returns the key's row in `id`.
   subroutine apply_override(cfg, text, id, err)
      type(config_t), intent(inout) :: cfg
      character(len=*), intent(in) :: text
      integer, intent(out) :: id
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
      call set_value(cfg, id, value, quoted, err)
      if (allocated(err)) call prefix_error(err, where)
   end subroutine apply_override

   !> Convert `value` to the type of key `id` and store it. Words are stored lower-case, file
   !> names verbatim. Range and word checks wait for `validate`, so an override can still fix
   !> a bad file value; only what cannot be converted fails here.
   subroutine set_value(cfg, id, value, quoted, err)
      type(config_t), intent(inout) :: cfg
      integer, intent(in) :: id
      character(len=*), intent(in) :: value
      logical, intent(in) :: quoted
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: what
      real(dp) :: x
      integer :: n
      logical :: b

      select case (key_kinds(id))
      case (kind_word, kind_path)
         if (len(value) > config_len) then
            what = 'text longer than '//int_text(config_len)//' characters'
         else if (has_control_character(value)) then
            ! a newline would break the echo, which must reload as a case file
            what = 'text with a control character, got '//quote(excerpt(value))
         else if (key_kinds(id) == kind_word) then
            call store_text(cfg, id, to_lower(trim(adjustl(value))))
         else
            call store_text(cfg, id, value)
         end if
      case (kind_real)
         if (quoted) then
            what = 'expected a real number, got the string '//quote(excerpt(value))
         else
            call scan_real(value, x, what)
            if (.not. allocated(what)) call store_real(cfg, id, x)
         end if
      case (kind_int)
         if (quoted) then
            what = 'expected an integer, got the string '//quote(excerpt(value))
         else
            call scan_integer(value, n, what)
            if (.not. allocated(what)) call store_int(cfg, id, n)
         end if
      case (kind_load)
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
      case (kind_logical)
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
      case (k_domain); cfg%mesh%domain = s
      case (k_mesh_file); cfg%mesh%file = s
      case (k_exact); cfg%problem%exact = s
      case (k_cfun); cfg%newton%cfun = s
      case (k_linear); cfg%newton%linear = s
      case (k_precond); cfg%gmres%precond = s
      case (k_initial); cfg%newton%initial = s
      case (k_line_search); cfg%newton%line_search = s
      case (k_fb_finish); cfg%newton%fb_finish = s
      case (k_forcing); cfg%gmres%forcing = s
      case (k_flux); cfg%estimate%flux = s
      case (k_criteria); cfg%estimate%criteria = s
      case (k_output_file); cfg%output%file = s
      case (k_f1); cfg%problem%f1_formula = s
      case (k_f2); cfg%problem%f2_formula = s
      case (k_f1_file); cfg%problem%f1_file = s
      case (k_f2_file); cfg%problem%f2_file = s
      end select
   end subroutine store_text

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

   !> The rules of docs/input.md, in table order; the first violation is reported where the
   !> offending value came from. Each check does nothing once `err` is set.
   subroutine validate(cfg, origin, err)
      type(config_t), intent(in) :: cfg
      type(string_t), intent(in) :: origin(:)
      type(error_t), allocatable, intent(out) :: err

      associate (m => cfg%mesh, p => cfg%problem, n => cfg%newton, g => cfg%gmres)
         call check_word(err, origin, k_domain, m%domain, [character(len=8) :: 'disk', 'square', 'gmsh'])
         call require(err, origin, k_domain, m%domain /= 'gmsh' .or. len_trim(m%file) > 0, &
                      "mesh.file must name the mesh when mesh.domain='gmsh'")
         call require(err, origin, k_mesh_file, m%domain == 'gmsh' .or. len_trim(m%file) == 0, &
                      "mesh.file is only read when mesh.domain='gmsh' (here domain='"//trim(m%domain)//"')")
         call check_real(err, origin, k_coarse_h, m%coarse_h, ge=1.0e-4_dp, le=2.0_dp)
         call check_int(err, origin, k_levels, m%levels, 0, 12)
         call check_real(err, origin, k_boundary_h, m%boundary_h, ge=0.0_dp, le=2.0_dp)
         ! only once both are known to be finite: comparing a NaN traps in debug builds
         if (.not. allocated(err)) &
            call require(err, origin, k_boundary_h, m%boundary_h <= m%coarse_h, &
                         'mesh.boundary_h must not exceed mesh.coarse_h (0 chooses it automatically)')
         call require(err, origin, k_boundary_h, m%boundary_h == 0.0_dp .or. m%domain == 'disk', &
                      "mesh.boundary_h is only used with mesh.domain='disk'")

         call check_real(err, origin, k_mu1, p%mu1, gt=0.0_dp)
         call check_real(err, origin, k_mu2, p%mu2, gt=0.0_dp)
         call check_load(err, origin, k_f1, p%f1, p%f1_formula)
         call check_load(err, origin, k_f2, p%f2, p%f2_formula)
         call check_real(err, origin, k_g, p%g, gt=0.0_dp)
         call check_word(err, origin, k_exact, p%exact, [character(len=8) :: 'none', 'radial', 'bbbv'])
         ! on a Gmsh mesh the mesh reader checks that its boundary lies on the unit circle
         call require(err, origin, k_exact, p%exact == 'none' .or. m%domain /= 'square', &
                      "exact='"//trim(p%exact)//"' needs the unit disk: mesh.domain='disk' or a Gmsh mesh of "// &
                      "the disk (here '"//trim(m%domain)//"')")
         call check_load_file(err, origin, k_f1_file, p%f1_file, p%f1_formula, 'f1')
         call check_load_file(err, origin, k_f2_file, p%f2_file, p%f2_formula, 'f2')
         call require(err, origin, k_exact, p%exact == 'none' .or. len_trim(p%f1_formula // p%f2_formula // &
                      p%f1_file // p%f2_file) == 0, "exact='"//trim(p%exact)//"' has its own loads: "// &
                      'f1 and f2 must be numbers, and f1_file, f2_file empty')

         call check_word(err, origin, k_cfun, n%cfun, [character(len=8) :: 'min', 'fb'])
         call check_word(err, origin, k_linear, n%linear, [character(len=8) :: 'direct', 'gmres', 'adaptive'])
         call check_int(err, origin, k_newton_max_it, n%max_it, 1, 100000)
         call check_real(err, origin, k_tol, n%tol, gt=0.0_dp, lt=1.0_dp)
         call check_real(err, origin, k_gamma_lin, n%gamma_lin, gt=0.0_dp, le=1.0_dp)
         call check_word(err, origin, k_initial, n%initial, [character(len=8) :: 'paper', 'nested'])
         call check_word(err, origin, k_line_search, n%line_search, [character(len=8) :: 'auto', 'on', 'off'])
         call check_word(err, origin, k_fb_finish, n%fb_finish, [character(len=10) :: 'active_set', 'none'])

         call check_int(err, origin, k_restart, g%restart, 1, 1000)
         call check_int(err, origin, k_gmres_max_it, g%max_it, 1, huge(1))
         call check_real(err, origin, k_rtol, g%rtol, gt=0.0_dp, lt=1.0_dp)
         call check_word(err, origin, k_precond, g%precond, [character(len=8) :: 'mg', 'ilu0', 'jacobi', 'none'])
         call check_word(err, origin, k_forcing, g%forcing, [character(len=8) :: 'paper', 'fixed'])
      end associate

      call check_real(err, origin, k_gamma_alg, cfg%estimate%gamma_alg, gt=0.0_dp, le=1.0_dp)
      call check_int(err, origin, k_every, cfg%estimate%every, 0, 100000)
      call check_word(err, origin, k_flux, cfg%estimate%flux, [character(len=8) :: 'rt1', 'rt0'])
      call check_int(err, origin, k_alg_levels, cfg%estimate%alg_levels, 1, 13)
      call check_word(err, origin, k_criteria, cfg%estimate%criteria, [character(len=8) :: 'global', 'local'])
   end subroutine validate

   !> A load: finite when a number, parsed when a formula (the message gives the column).
   subroutine check_load(err, origin, id, x, formula)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      real(dp), intent(in) :: x
      character(len=*), intent(in) :: formula

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where

      if (allocated(err)) return
      if (len_trim(formula) == 0) then
         call check_real(err, origin, id, x)
         return
      end if
      call parse_formula(trim(formula), f, where, why)
      if (allocated(why)) call fail(err, origin, id, 'formula '//quote(excerpt(trim(formula)))//': column '// &
                                    int_text(where)//': '//why)
   end subroutine check_load

   !> 'FILE:DATASET', and not together with a formula for the same load.
   subroutine check_load_file(err, origin, id, spec, formula, load)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      character(len=*), intent(in) :: spec, formula, load

      integer :: colon

      if (allocated(err) .or. len_trim(spec) == 0) return
      colon = index(spec, ':', back=.true.)
      if (colon <= 1 .or. colon >= len_trim(spec)) then
         call fail(err, origin, id, "must be 'FILE:DATASET', e.g. 'loads.h5:/"//load//"', got "// &
                   quote(excerpt(trim(spec))))
      else if (len_trim(formula) > 0) then
         call fail(err, origin, id, 'and a formula for '//load//' are both given: choose one')
      end if
   end subroutine check_load_file

   !> A rule across keys, blamed on key `id`: `<origin>: &group: what`.
   subroutine require(err, origin, id, ok, what)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      logical, intent(in) :: ok
      character(len=*), intent(in) :: what

      if (allocated(err) .or. ok) return
      call make_error(err, exit_bad_input, origin(id)%s//': &'//trim(group_names(key_group(id))), what)
   end subroutine require

   !> `<origin>: &group: key must be ...`
   subroutine fail(err, origin, id, what)
      type(error_t), allocatable, intent(out) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      character(len=*), intent(in) :: what

      call make_error(err, exit_bad_input, origin(id)%s//': &'//trim(group_names(key_group(id))), &
                      trim(key_names(id))//' '//what)
   end subroutine fail

   subroutine check_word(err, origin, id, value, allowed)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      character(len=*), intent(in) :: value
      character(len=*), intent(in) :: allowed(:)

      character(len=:), allocatable :: list
      integer :: i

      if (allocated(err)) return
      if (any(allowed == value)) return
      list = ''
      do i = 1, size(allowed)
         if (i > 1) list = list//', '
         list = list//quote(trim(allowed(i)))
      end do
      call fail(err, origin, id, 'must be one of '//list//', got '//quote(excerpt(trim(value))))
   end subroutine check_word

   !> Finite, and within the bounds given (`gt`: >, `ge`: >=, `lt`: <, `le`: <=). Finiteness is
   !> tested first: comparing a NaN would trap in debug builds.
   subroutine check_real(err, origin, id, x, gt, ge, lt, le)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      real(dp), intent(in) :: x
      real(dp), intent(in), optional :: gt, ge, lt, le

      character(len=:), allocatable :: got

      if (allocated(err)) return
      got = ', got '//number_text(x)
      if (.not. ieee_is_finite(x)) then
         call fail(err, origin, id, 'must be finite'//got)
         return
      end if
      if (present(gt)) then
         if (.not. x > gt) call fail(err, origin, id, 'must be > '//number_text(gt)//got)
      end if
      if (allocated(err)) return
      if (present(ge)) then
         if (.not. x >= ge) call fail(err, origin, id, 'must be >= '//number_text(ge)//got)
      end if
      if (allocated(err)) return
      if (present(lt)) then
         if (.not. x < lt) call fail(err, origin, id, 'must be < '//number_text(lt)//got)
      end if
      if (allocated(err)) return
      if (present(le)) then
         if (.not. x <= le) call fail(err, origin, id, 'must be <= '//number_text(le)//got)
      end if
   end subroutine check_real

   !> A real for messages: as echoed, but whole numbers without '.0' ('must be > 0, got -1').
   function number_text(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s

      s = format_real(x)
      if (len(s) > 2) then
         if (s(len(s) - 1:) == '.0') s = s(1:len(s) - 2)
      end if
   end function number_text

   subroutine check_int(err, origin, id, n, lo, hi)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id, n, lo, hi

      if (allocated(err)) return
      if (n < lo) then
         call fail(err, origin, id, 'must be >= '//int_text(lo)//', got '//int_text(n))
      else if (n > hi) then
         call fail(err, origin, id, 'must be <= '//int_text(hi)//', got '//int_text(n))
      end if
   end subroutine check_int

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
            if (key_group(id) /= gid) cycle
            text = text//'   '//trim(key_names(id))//' = '//value_text(cfg, id)//nl
         end do
         text = text//'/'//nl
      end do
   end function config_echo

   !> The namelist literal of key `id`.
   function value_text(cfg, id) result(s)
      type(config_t), intent(in) :: cfg
      integer, intent(in) :: id
      character(len=:), allocatable :: s

      select case (id)
      case (k_domain); s = quote(trim(cfg%mesh%domain))
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
      case (k_exact); s = quote(trim(cfg%problem%exact))
      case (k_cfun); s = quote(trim(cfg%newton%cfun))
      case (k_linear); s = quote(trim(cfg%newton%linear))
      case (k_newton_max_it); s = int_text(cfg%newton%max_it)
      case (k_tol); s = format_real(cfg%newton%tol)
      case (k_gamma_lin); s = format_real(cfg%newton%gamma_lin)
      case (k_restart); s = int_text(cfg%gmres%restart)
      case (k_gmres_max_it); s = int_text(cfg%gmres%max_it)
      case (k_rtol); s = format_real(cfg%gmres%rtol)
      case (k_precond); s = quote(trim(cfg%gmres%precond))
      case (k_initial); s = quote(trim(cfg%newton%initial))
      case (k_line_search); s = quote(trim(cfg%newton%line_search))
      case (k_fb_finish); s = quote(trim(cfg%newton%fb_finish))
      case (k_forcing); s = quote(trim(cfg%gmres%forcing))
      case (k_every); s = int_text(cfg%estimate%every)
      case (k_flux); s = quote(trim(cfg%estimate%flux))
      case (k_alg_levels); s = int_text(cfg%estimate%alg_levels)
      case (k_criteria); s = quote(trim(cfg%estimate%criteria))
      case (k_gamma_alg); s = format_real(cfg%estimate%gamma_alg)
      case (k_enabled); s = logical_text(cfg%estimate%enabled)
      case (k_output_file); s = quote(trim(cfg%output%file))
      case (k_fields); s = logical_text(cfg%output%fields)
      case (k_estimators); s = logical_text(cfg%output%estimators)
      case (k_history); s = logical_text(cfg%output%history)
      case (k_xdmf); s = logical_text(cfg%output%xdmf)
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

   pure integer function find_group(name) result(gid)
      character(len=*), intent(in) :: name

      do gid = 1, n_groups
         if (group_names(gid) == name) return
      end do
      gid = 0
   end function find_group

   pure integer function find_key(gid, key) result(id)
      integer, intent(in) :: gid
      character(len=*), intent(in) :: key

      do id = 1, n_keys
         if (key_group(id) == gid .and. key_names(id) == key) return
      end do
      id = 0
   end function find_key

   pure function group_list() result(list)
      character(len=:), allocatable :: list

      integer :: gid

      list = trim(group_names(1))
      do gid = 2, n_groups
         list = list//', '//trim(group_names(gid))
      end do
   end function group_list

   pure function key_list(gid) result(list)
      integer, intent(in) :: gid
      character(len=:), allocatable :: list

      integer :: id

      list = ''
      do id = 1, n_keys
         if (key_group(id) /= gid) cycle
         if (len(list) > 0) list = list//', '
         list = list//trim(key_names(id))
      end do
   end function key_list
end module twomem_input_config
