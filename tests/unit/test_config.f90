!> Tests of the case input: defaults, a full file, every kind of error with its location,
!> overrides, case-insensitivity, and the echo that must reload to the identical configuration.
module test_config
   use twomem_base_kinds, only: dp, i8
   use twomem_base_errors, only: exit_bad_input
   use twomem_base_options, only: c_function_min, c_function_fb, domain_disk, domain_gmsh, domain_square, exact_none, &
      method_direct, method_gmres, method_adaptive, precond_mg, precond_jacobi
   use twomem_input_config, only: config_t, string_t, load_config, load_config_text, config_echo
   use twomem_input_values, only: format_real, scan_real, scan_integer, scan_logical
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   implicit none
   private

   public :: collect_config
   ! helpers shared with test_config_robustness
   public :: write_case, no_overrides, words, expect_error

   character, parameter :: nl = new_line('a')

contains

   subroutine collect_config(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('defaults_empty_groups', test_defaults_empty_groups), &
               new_unittest('defaults_no_groups', test_defaults_no_groups), &
               new_unittest('full_file', test_full_file), &
               new_unittest('missing_file', test_missing_file), &
               new_unittest('syntax_errors', test_syntax_errors), &
               new_unittest('unknown_and_repeated', test_unknown_and_repeated), &
               new_unittest('type_errors', test_type_errors), &
               new_unittest('range_errors', test_range_errors), &
               new_unittest('word_and_cross_rules', test_word_and_cross_rules), &
               new_unittest('non_finite_rejected', test_non_finite), &
               new_unittest('overrides', test_overrides), &
               new_unittest('override_fixes_file', test_override_fixes_file), &
               new_unittest('override_errors', test_override_errors), &
               new_unittest('case_insensitive', test_case_insensitive), &
               new_unittest('echo_round_trip', test_echo_round_trip), &
               new_unittest('output_file_resolved', test_output_file), &
               new_unittest('unquoted_path_in_file', test_unquoted_path), &
               new_unittest('value_scanners', test_value_scanners), &
               new_unittest('real_format_round_trip', test_real_format)]
   end subroutine collect_config

   ! ---------------------------------------------------------------- helpers

   !> `TWOMEM_TEST_TMP/name`, with `content` written to it.
   function write_case(name, content) result(path)
      character(len=*), intent(in) :: name, content
      character(len=:), allocatable :: path

      character(len=1024) :: dir
      integer :: unit, length, stat

      call get_environment_variable('TWOMEM_TEST_TMP', dir, length, stat)
      ! never litter the working tree: the scratch directory comes from ctest
      if (stat /= 0 .or. length == 0) error stop 'TWOMEM_TEST_TMP is not set (run through ctest)'
      path = trim(dir)//'/'//name
      open (newunit=unit, file=path, status='replace', action='write', access='stream', form='formatted')
      write (unit, '(a)', advance='no') content
      close (unit)
   end function write_case

   function no_overrides() result(o)
      type(string_t), allocatable :: o(:)

      allocate (o(0))
   end function no_overrides

   function words(a, b, c, d, e, f) result(o)
      character(len=*), intent(in) :: a
      character(len=*), intent(in), optional :: b, c, d, e, f
      type(string_t), allocatable :: o(:)

      integer :: n

      n = 1 + count([present(b), present(c), present(d), present(e), present(f)])
      allocate (o(n))
      o(1)%s = a
      if (present(b)) o(2)%s = b
      if (present(c)) o(3)%s = c
      if (present(d)) o(4)%s = d
      if (present(e)) o(5)%s = e
      if (present(f)) o(6)%s = f
   end function words

   !> Load `content` as file `name` (with `overrides`) and expect a bad-input error whose
   !> message names the file (or the override) and contains every one of `needles`.
   subroutine expect_error(err, name, content, needles, overrides, in_file)
      type(error_t), allocatable, intent(inout) :: err
      character(len=*), intent(in) :: name, content
      character(len=*), intent(in) :: needles(:)
      type(string_t), intent(in), optional :: overrides(:)
      !> the error is in the file, so the message names it (default); else it names the override
      logical, intent(in), optional :: in_file

      type(config_t) :: cfg
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path
      integer :: i

      if (allocated(err)) return
      path = write_case(name, content)
      if (present(overrides)) then
         call load_config(path, overrides, cfg, got)
      else
         call load_config(path, no_overrides(), cfg, got)
      end if
      call check(err, allocated(got), name//': expected an error, loaded fine')
      if (allocated(err)) return
      call check(err, got%code == exit_bad_input, name//': error code 2')
      if (present(in_file)) then
         if (.not. in_file) path = 'override '''
      end if
      call check(err, index(got%message, path) > 0, name//': message names the source: '//got%message)
      call check(err, index(got%message, new_line('a')) == 0, name//': one line: '//got%message)
      do i = 1, size(needles)
         call check(err, index(got%message, trim(needles(i))) > 0, &
                    name//": message lacks '"//trim(needles(i))//"': "//got%message)
      end do
   end subroutine expect_error

   logical function same_real(a, b)
      real(dp), intent(in) :: a, b

      same_real = transfer(a, 0_i8) == transfer(b, 0_i8)
   end function same_real

   !> Name of the first component where `a` and `b` differ ('' if none); reals compared bitwise.
   function config_diff(a, b) result(name)
      type(config_t), intent(in) :: a, b
      character(len=:), allocatable :: name

      name = ''
      if (a%mesh%domain /= b%mesh%domain) name = 'mesh%domain'
      if (a%mesh%file /= b%mesh%file) name = 'mesh%file'
      if (.not. same_real(a%mesh%coarse_h, b%mesh%coarse_h)) name = 'mesh%coarse_h'
      if (a%mesh%levels /= b%mesh%levels) name = 'mesh%levels'
      if (.not. same_real(a%problem%mu1, b%problem%mu1)) name = 'problem%mu1'
      if (.not. same_real(a%problem%mu2, b%problem%mu2)) name = 'problem%mu2'
      if (.not. same_real(a%problem%f1, b%problem%f1)) name = 'problem%f1'
      if (.not. same_real(a%problem%f2, b%problem%f2)) name = 'problem%f2'
      if (.not. same_real(a%problem%g, b%problem%g)) name = 'problem%g'
      if (a%problem%exact /= b%problem%exact) name = 'problem%exact'
      if (a%newton%cfun /= b%newton%cfun) name = 'newton%cfun'
      if (a%newton%linear /= b%newton%linear) name = 'newton%linear'
      if (a%newton%max_it /= b%newton%max_it) name = 'newton%max_it'
      if (.not. same_real(a%newton%tol, b%newton%tol)) name = 'newton%tol'
      if (.not. same_real(a%newton%gamma_lin, b%newton%gamma_lin)) name = 'newton%gamma_lin'
      if (a%gmres%restart /= b%gmres%restart) name = 'gmres%restart'
      if (a%gmres%max_it /= b%gmres%max_it) name = 'gmres%max_it'
      if (.not. same_real(a%gmres%rtol, b%gmres%rtol)) name = 'gmres%rtol'
      if (a%gmres%precond /= b%gmres%precond) name = 'gmres%precond'
      if (.not. same_real(a%estimate%gamma_alg, b%estimate%gamma_alg)) name = 'estimate%gamma_alg'
      if (a%estimate%enabled .neqv. b%estimate%enabled) name = 'estimate%enabled'
      if (a%output%file /= b%output%file) name = 'output%file'
      if (a%output%fields .neqv. b%output%fields) name = 'output%fields'
      if (a%output%estimators .neqv. b%output%estimators) name = 'output%estimators'
      if (a%output%history .neqv. b%output%history) name = 'output%history'
      if (a%output%xdmf .neqv. b%output%xdmf) name = 'output%xdmf'
      if (.not. same_real(a%adapt%tol, b%adapt%tol)) name = 'adapt%tol'
      if (.not. same_real(a%adapt%theta, b%adapt%theta)) name = 'adapt%theta'
      if (a%adapt%max_steps /= b%adapt%max_steps) name = 'adapt%max_steps'
      if (a%adapt%max_vertices /= b%adapt%max_vertices) name = 'adapt%max_vertices'
   end function config_diff

   !> Loads `content` as `name` and checks that it equals the defaults (output file resolved).
   subroutine expect_defaults(err, name, content)
      type(error_t), allocatable, intent(inout) :: err
      character(len=*), intent(in) :: name, content

      type(config_t) :: cfg, ref
      character(len=:), allocatable :: path

      path = write_case(name//'.nml', content)
      call load_config(path, no_overrides(), cfg, err)
      if (allocated(err)) return
      ref%output%file = 'results/'//name//'.h5'
      call check(err, config_diff(cfg, ref) == '', name//': differs from the defaults in '//config_diff(cfg, ref))
      call check(err, cfg%case_name == name, name//': case name')
      call check(err, cfg%source == path, name//': source')
   end subroutine expect_defaults

   ! ---------------------------------------------------------------- tests

   subroutine test_defaults_empty_groups(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: ref

      ! the documented defaults, spelled out once
      call check(err, ref%mesh%domain == domain_disk .and. ref%mesh%file == '' .and. ref%mesh%levels == 4 &
                 .and. ref%mesh%coarse_h == 0.25_dp, 'mesh defaults')
      call check(err, ref%problem%mu1 == 1 .and. ref%problem%mu2 == 1 .and. ref%problem%f1 == -0.25_dp &
                 .and. ref%problem%f2 == 0.25_dp .and. ref%problem%g == 0.05_dp .and. ref%problem%exact == exact_none, &
                 'problem defaults')
      call check(err, ref%newton%cfun == c_function_min .and. ref%newton%linear == method_adaptive .and. ref%newton%max_it == 100 &
                 .and. ref%newton%tol == 1.0e-10_dp .and. ref%newton%gamma_lin == 0.3_dp, 'newton defaults')
      call check(err, ref%gmres%restart == 30 .and. ref%gmres%max_it == 5000 .and. ref%gmres%rtol == 1.0e-10_dp &
                 .and. ref%gmres%precond == precond_mg, 'gmres defaults')
      call check(err, ref%estimate%gamma_alg == 0.3_dp .and. ref%estimate%enabled, 'estimate defaults')
      call check(err, ref%output%file == '' .and. ref%output%fields .and. ref%output%estimators &
                 .and. ref%output%history .and. ref%output%xdmf, 'output defaults')
      if (allocated(err)) return
      call expect_defaults(err, 'config_empty_groups', &
                           '&mesh /'//nl//'&problem'//nl//'/'//nl//'&newton /&gmres /'//nl// &
                           '$estimate $end'//nl//'&output &end'//nl)
   end subroutine test_defaults_empty_groups

   subroutine test_defaults_no_groups(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_defaults(err, 'config_no_groups', '! only a comment'//nl//nl//'   '//nl)
      if (allocated(err)) return
      call expect_defaults(err, 'config_empty_file', '')
   end subroutine test_defaults_no_groups

   subroutine test_full_file(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      character(len=:), allocatable :: path

      path = write_case('config_full.nml', &
                        '! a full case'//nl// &
                        '&mesh domain = "gmsh", file = ''meshes/it''''s a "mesh".msh'' ! quoted quotes'//nl// &
                        '      coarse_h=0.125, levels = 6,'//nl// &
                        '/'//nl// &
                        '&problem mu1 = 2.0 mu2 = 3'//nl// &
                        '   f1 = -1.d-3'//nl// &
                        '   f2 = +.5e1, g = 0.1'//nl// &
                        '   exact = ''none'' /'//nl// &
                        '$newton cfun = ''fb'' linear = ''gmres'' max_it = 7 tol = 1e-8 gamma_lin = 1 $end'//nl// &
                        '&gmres restart = 50, max_it = 123, rtol = 1.5D-6, precond = ''jacobi'' /'//nl// &
                        '&estimate gamma_alg = 0.5 enabled = F /'//nl// &
                        '&output file = "out/full.h5", fields = .false., estimators = .true.,'//nl// &
                        '   history = false, xdmf = T'//nl// &
                        '/'//nl)
      call load_config(path, no_overrides(), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%mesh%domain == domain_gmsh, 'domain')
      call check(err, cfg%mesh%file == 'meshes/it''s a "mesh".msh', 'file with quotes: '//trim(cfg%mesh%file))
      call check(err, cfg%mesh%coarse_h == 0.125_dp .and. cfg%mesh%levels == 6, 'coarse_h, levels')
      call check(err, cfg%problem%mu1 == 2 .and. cfg%problem%mu2 == 3, 'mu')
      call check(err, cfg%problem%f1 == -1.0e-3_dp .and. cfg%problem%f2 == 5 .and. cfg%problem%g == 0.1_dp, 'f, g')
      call check(err, cfg%problem%exact == exact_none, 'exact')
      call check(err, cfg%newton%cfun == c_function_fb .and. cfg%newton%linear == method_gmres, 'cfun, linear')
      call check(err, cfg%newton%max_it == 7 .and. cfg%newton%tol == 1.0e-8_dp .and. cfg%newton%gamma_lin == 1, &
                 'newton numbers')
      call check(err, cfg%gmres%restart == 50 .and. cfg%gmres%max_it == 123 .and. cfg%gmres%rtol == 1.5e-6_dp &
                 .and. cfg%gmres%precond == precond_jacobi, 'gmres')
      call check(err, cfg%estimate%gamma_alg == 0.5_dp .and. .not. cfg%estimate%enabled, 'estimate')
      call check(err, cfg%output%file == 'out/full.h5', 'output file')
      call check(err, .not. cfg%output%fields .and. cfg%output%estimators .and. .not. cfg%output%history &
                 .and. cfg%output%xdmf, 'output switches')
      call check(err, cfg%case_name == 'config_full', 'case name')
   end subroutine test_full_file

   subroutine test_missing_file(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      type(error_t), allocatable :: got

      call load_config('no/such/dir/missing.nml', no_overrides(), cfg, got)
      call check(err, allocated(got), 'missing file is an error')
      if (allocated(err)) return
      call check(err, got%code == exit_bad_input, 'code 2')
      call check(err, index(got%message, 'no/such/dir/missing.nml') > 0, 'names the path: '//got%message)
      if (allocated(err)) return
      deallocate (got)
      call load_config('.', no_overrides(), cfg, got)
      call check(err, allocated(got), 'a directory is an error')
   end subroutine test_missing_file

   subroutine test_syntax_errors(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_unterminated.nml', '&mesh'//nl//' domain = ''disk'//nl//'/'//nl, &
                        [character(len=40) :: ':2:', '&mesh', 'domain', 'unterminated string'])
      call expect_error(err, 'config_no_slash.nml', '&mesh levels = 3'//nl//nl, &
                        [character(len=40) :: ':1:', '&mesh', "missing '/'"])
      call expect_error(err, 'config_no_slash2.nml', '&mesh levels = 3'//nl//'&problem /'//nl, &
                        [character(len=40) :: ':2:', '&mesh', "missing '/'", '&problem'])
      call expect_error(err, 'config_stray_before.nml', 'levels = 3'//nl//'&mesh /'//nl, &
                        [character(len=40) :: ':1:', 'stray text outside groups', 'levels'])
      call expect_error(err, 'config_stray_after.nml', '&mesh /'//nl//nl//'junk'//nl, &
                        [character(len=40) :: ':3:', 'stray text', 'junk'])
      call expect_error(err, 'config_missing_value.nml', '&mesh'//nl//'levels ='//nl//'coarse_h = 0.5 /'//nl, &
                        [character(len=40) :: ':2:', '&mesh', 'levels', 'missing value'])
      call expect_error(err, 'config_missing_value2.nml', '&mesh levels = , /', &
                        [character(len=40) :: ':1:', 'levels', 'missing value'])
      call expect_error(err, 'config_missing_value3.nml', '&mesh coarse_h = 0.5'//nl//'levels = /', &
                        [character(len=40) :: ':2:', 'levels', 'missing value'])
      call expect_error(err, 'config_no_equals.nml', '&mesh'//nl//'levels 3 /', &
                        [character(len=40) :: ':2:', 'levels', "expected '='"])
      call expect_error(err, 'config_array.nml', '&problem'//nl//'mu1 = 1.0 2.0 /', &
                        [character(len=40) :: ':2:', '&problem', 'arrays'])
      call expect_error(err, 'config_array_comma.nml', '&problem'//nl//'mu1 = 1.0, 2.0 /', &
                        [character(len=40) :: ':2:', '&problem', 'arrays'])
      call expect_error(err, 'config_element.nml', '&problem'//nl//'mu1(1) = 1.0 /', &
                        [character(len=40) :: ':2:', 'mu1(1)', 'array elements'])
      call expect_error(err, 'config_repeat.nml', '&problem'//nl//nl//'mu1 = 2*1.0 /', &
                        [character(len=40) :: ':3:', 'mu1', 'repeat count'])
      call expect_error(err, 'config_no_group_name.nml', '& /', [character(len=40) :: ':1:', 'group name'])
   end subroutine test_syntax_errors

   subroutine test_unknown_and_repeated(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_unknown_group.nml', '&mesh /'//nl//'&meshes levels = 3 /', &
                        [character(len=60) :: ':2:', '&meshes', 'unknown group', 'mesh, problem, newton'])
      call expect_error(err, 'config_group_twice.nml', '&mesh /'//nl//'&problem /'//nl//'&MESH /', &
                        [character(len=60) :: ':3:', '&mesh', 'twice', 'line 1'])
      call expect_error(err, 'config_unknown_key.nml', '&mesh'//nl//'  levle = 3'//nl//'/', &
                        [character(len=60) :: ':2:', '&mesh', 'levle', 'unknown key', &
                         'valid keys: domain, file, coarse_h, levels'])
      call expect_error(err, 'config_key_twice.nml', '&newton tol = 1e-8'//nl//'  TOL = 1e-9 /', &
                        [character(len=60) :: ':2:', '&newton', 'tol', 'twice', 'line 1'])
   end subroutine test_unknown_and_repeated

   subroutine test_type_errors(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_type_real.nml', '&mesh'//nl//'coarse_h = abc /', &
                        [character(len=60) :: ':2:', '&mesh', 'coarse_h', "expected a real number, got 'abc'"])
      call expect_error(err, 'config_type_real2.nml', '&newton tol = 1e-3e4 /', &
                        [character(len=60) :: ':1:', 'tol', 'expected a real number'])
      call expect_error(err, 'config_type_quoted.nml', '&newton tol = ''1e-3'' /', &
                        [character(len=60) :: 'tol', 'expected a real number', 'string'])
      call expect_error(err, 'config_type_int.nml', '&mesh levels = 1.5 /', &
                        [character(len=60) :: ':1:', 'levels', "expected an integer, got '1.5'"])
      call expect_error(err, 'config_type_int_big.nml', '&gmres max_it = 99999999999 /', &
                        [character(len=60) :: 'max_it', 'out of range'])
      call expect_error(err, 'config_type_logical.nml', '&output'//nl//'xdmf = yes /', &
                        [character(len=60) :: ':2:', '&output', 'xdmf', 'expected a logical'])
      call expect_error(err, 'config_type_logical2.nml', '&estimate enabled = 1 /', &
                        [character(len=60) :: 'enabled', 'expected a logical'])
   end subroutine test_type_errors

   subroutine test_range_errors(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_range_mu1.nml', '&problem'//nl//'mu1 = -1 /', &
                        [character(len=60) :: ':2:', '&problem', 'mu1 must be > 0', 'got -1'])
      call expect_error(err, 'config_range_g.nml', '&problem g = 0 /', &
                        [character(len=60) :: ':1:', 'g must be > 0'])
      call expect_error(err, 'config_range_h.nml', '&mesh'//nl//nl//'coarse_h = 5 /', &
                        [character(len=60) :: ':3:', '&mesh', 'coarse_h must be <= 2', 'got 5'])
      call expect_error(err, 'config_range_h2.nml', '&mesh coarse_h = 1e-5 /', &
                        [character(len=60) :: 'coarse_h must be >= 0.0001'])
      call expect_error(err, 'config_range_levels.nml', '&mesh levels = 13 /', &
                        [character(len=60) :: 'levels must be <= 12', 'got 13'])
      call expect_error(err, 'config_range_levels2.nml', '&mesh levels = -1 /', &
                        [character(len=60) :: 'levels must be >= 0'])
      call expect_error(err, 'config_range_tol.nml', '&newton tol = 1 /', &
                        [character(len=60) :: '&newton', 'tol must be < 1'])
      call expect_error(err, 'config_range_gamma.nml', '&newton gamma_lin = 1.5 /', &
                        [character(len=60) :: 'gamma_lin must be <= 1'])
      call expect_error(err, 'config_range_maxit.nml', '&newton max_it = 0 /', &
                        [character(len=60) :: '&newton', 'max_it must be >= 1'])
      call expect_error(err, 'config_range_restart.nml', '&gmres restart = 1001 /', &
                        [character(len=60) :: '&gmres', 'restart must be <= 1000'])
      call expect_error(err, 'config_range_gmaxit.nml', '&gmres max_it = 0 /', &
                        [character(len=60) :: '&gmres', 'max_it must be >= 1'])
      call expect_error(err, 'config_range_rtol.nml', '&gmres rtol = 0 /', &
                        [character(len=60) :: 'rtol must be > 0'])
      call expect_error(err, 'config_range_alg.nml', '&estimate gamma_alg = 0 /', &
                        [character(len=60) :: '&estimate', 'gamma_alg must be > 0'])
   end subroutine test_range_errors

   subroutine test_word_and_cross_rules(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_word_domain.nml', '&mesh'//nl//'domain = ''circle'' /', &
                        [character(len=60) :: ':2:', '&mesh', 'domain must be one of', "'disk', 'square', 'gmsh'", &
                         "got 'circle'"])
      call expect_error(err, 'config_word_precond.nml', '&gmres precond = ''ILU'' /', &
                        [character(len=60) :: '&gmres', 'precond', "'mg', 'ilu0', 'jacobi', 'none'", "got 'ilu'"])
      call expect_error(err, 'config_word_cfun.nml', '&newton cfun = '''' /', &
                        [character(len=60) :: 'cfun must be one of', "'min', 'fb'"])
      call expect_error(err, 'config_word_linear.nml', '&newton linear = "umfpack" /', &
                        [character(len=60) :: 'linear must be one of', "'direct', 'gmres', 'adaptive'"])
      call expect_error(err, 'config_word_exact.nml', '&problem exact = ''yes'' /', &
                        [character(len=60) :: 'exact must be one of', "'none', 'radial', 'bbbv'"])
      call expect_error(err, 'config_file_not_gmsh.nml', '&mesh'//nl//'file = ''a.msh'' /', &
                        [character(len=60) :: ':2:', "mesh.file is only read when mesh.domain='gmsh'"])
      call expect_error(err, 'config_gmsh_no_file.nml', '&mesh domain = ''gmsh'' /', &
                        [character(len=60) :: ':1:', '&mesh', 'mesh.file'])
      call expect_error(err, 'config_exact_square.nml', '&mesh domain = ''square'' /'//nl//'&problem'//nl// &
                        'exact = ''radial'' /', [character(len=60) :: ':3:', '&problem', "needs the unit disk"])
   end subroutine test_word_and_cross_rules

   subroutine test_non_finite(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_nan.nml', '&problem'//nl//'mu1 = nan /', &
                        [character(len=60) :: ':2:', '&problem', 'mu1 must be finite', 'NaN'])
      call expect_error(err, 'config_inf.nml', '&problem f1 = -Inf /', &
                        [character(len=60) :: 'f1 must be finite', '-Infinity'])
      call expect_error(err, 'config_infinity.nml', '&newton tol = +infinity /', &
                        [character(len=60) :: 'tol must be finite'])
      call expect_error(err, 'config_overflow.nml', '&mesh coarse_h = 1e999 /', &
                        [character(len=60) :: 'coarse_h', 'out of range'])
      call expect_error(err, 'config_nan_override.nml', '', [character(len=60) :: "override 'problem.g=NaN'", &
                        'g must be finite'], words('problem.g=NaN'), in_file=.false.)
   end subroutine test_non_finite

   subroutine test_overrides(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      character(len=:), allocatable :: path

      path = write_case('config_over.nml', '&mesh levels = 2 /'//nl//'&newton cfun = ''min'' /'//nl)
      call load_config(path, words('newton.cfun=fb', 'output.file=out/a.h5', 'MESH.Levels=5', &
                                  "mesh.domain='Square'", ' problem.mu1 = 2.5 ', 'estimate.enabled=F'), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%newton%cfun == c_function_fb, 'unquoted word')
      call check(err, cfg%output%file == 'out/a.h5', 'unquoted path with a slash: '//trim(cfg%output%file))
      call check(err, cfg%mesh%levels == 5, 'override beats the file')
      call check(err, cfg%mesh%domain == domain_square, 'quoted word, lower-cased')
      call check(err, cfg%problem%mu1 == 2.5_dp, 'blanks around the override')
      call check(err, .not. cfg%estimate%enabled, 'logical')
      if (allocated(err)) return
      call load_config(path, words('mesh.levels=3', 'mesh.levels=7', 'output.file="q/it''s.h5"'), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%mesh%levels == 7, 'the last override wins')
      call check(err, cfg%output%file == 'q/it''s.h5', 'quoted path: '//trim(cfg%output%file))
   end subroutine test_overrides

   subroutine test_override_fixes_file(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      character(len=:), allocatable :: path

      path = write_case('config_fixable.nml', '&problem mu1 = -1 /'//nl//'&mesh file = ''x.msh'' /'//nl)
      call load_config(path, words('problem.mu1=1', 'mesh.domain=gmsh'), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%problem%mu1 == 1 .and. cfg%mesh%domain == domain_gmsh .and. cfg%mesh%file == 'x.msh', &
                 'fixed by overrides')
   end subroutine test_override_fixes_file

   subroutine test_override_errors(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_error(err, 'config_ov1.nml', '', [character(len=60) :: "override 'mesh.levels=x'", &
                        'expected an integer'], words('mesh.levels=x'), in_file=.false.)
      call expect_error(err, 'config_ov2.nml', '', [character(len=60) :: "override 'mesh.levels'", "no '='"], &
                        words('mesh.levels'), in_file=.false.)
      call expect_error(err, 'config_ov3.nml', '', [character(len=60) :: "override 'levels=3'", "no '.'"], &
                        words('levels=3'), in_file=.false.)
      call expect_error(err, 'config_ov4.nml', '', [character(len=60) :: "override 'mech.levels=3'", &
                        "unknown group 'mech'"], words('mech.levels=3'), in_file=.false.)
      call expect_error(err, 'config_ov5.nml', '', [character(len=60) :: "override 'mesh.level=3'", &
                        "unknown key 'level'", 'domain, file, coarse_h, levels'], words('mesh.level=3'), in_file=.false.)
      call expect_error(err, 'config_ov6.nml', '', [character(len=60) :: "override 'mesh.levels='", &
                        'missing value'], words('mesh.levels='), in_file=.false.)
      call expect_error(err, 'config_ov7.nml', '', [character(len=60) :: "override 'mesh.levels=20'", &
                        '&mesh', 'levels must be <= 12'], words('mesh.coarse_h=0.5', 'mesh.levels=20'), in_file=.false.)
      call expect_error(err, 'config_ov8.nml', '', [character(len=60) :: "override 'newton.tol=1e-3,5'", &
                        'expected a real number'], words('newton.tol=1e-3,5'), in_file=.false.)
      call expect_error(err, 'config_ov9.nml', '', [character(len=60) :: "override 'output.file='a.h5'", &
                        'unterminated'], words("output.file='a.h5"), in_file=.false.)
      call expect_error(err, 'config_ov10.nml', '&mesh levels = 20 /', [character(len=60) :: ':1:', &
                        'levels must be <= 12'], words('mesh.coarse_h=0.5'))
   end subroutine test_override_errors

   subroutine test_case_insensitive(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      character(len=:), allocatable :: path

      path = write_case('config_case.nml', '&MESH DOMAIN=''SQUARE'' Levels=2 /'//nl// &
                        '$Newton CFun = "FB", LINEAR = Direct $END'//nl// &
                        '&Output FILE = ''Out/Mixed.H5'' XDMF = .FALSE. /'//nl// &
                        '&gmres PRECOND = JACOBI RTOL = 1E-8 /'//nl)
      call load_config(path, no_overrides(), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%mesh%domain == domain_square .and. cfg%mesh%levels == 2, 'mesh')
      call check(err, cfg%newton%cfun == c_function_fb .and. cfg%newton%linear == method_direct, 'words lower-cased')
      call check(err, cfg%output%file == 'Out/Mixed.H5', 'file names verbatim')
      call check(err, .not. cfg%output%xdmf, 'logical')
      call check(err, cfg%gmres%precond == precond_jacobi .and. cfg%gmres%rtol == 1.0e-8_dp, 'gmres')
   end subroutine test_case_insensitive

   subroutine test_echo_round_trip(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg, back, defaults, back2
      character(len=:), allocatable :: path, text, path2
      character(len=12) :: keys(30) = [character(len=12) :: 'domain =', 'file =', 'coarse_h =', 'levels =', &
                                       'mu1 =', 'mu2 =', 'f1 =', 'f2 =', 'g =', 'exact =', 'cfun =', 'linear =', &
                                       'max_it =', 'tol =', 'gamma_lin =', 'restart =', 'rtol =', 'precond =', &
                                       'gamma_alg =', 'enabled =', 'fields =', 'estimators =', 'history =', &
                                       'xdmf =', '&estimate', '&output', '&adapt', 'theta =', 'max_steps =', &
                                       'max_vertices']
      integer :: i

      path = write_case('config_echo_src.nml', &
                        '&mesh domain = ''gmsh'', file = ''m/it''''s.msh'', coarse_h = 0.1, levels = 0 /'//nl// &
                        '&problem mu1 = 0.3333333333333333, mu2 = 1.0000000000000002, f1 = -0.0'//nl// &
                        '   f2 = 123456.789, g = 2.5e-300 /'//nl// &
                        '&newton cfun = ''fb'' linear = ''direct'' max_it = 100000 tol = 4.9e-10'//nl// &
                        '   gamma_lin = 0.7000000000000001 /'//nl// &
                        '&gmres restart = 1 max_it = 2147483647 rtol = 0.9999999999999999 precond = ''none'' /'//nl// &
                        '&estimate gamma_alg = 1e-7 enabled = .false. /'//nl// &
                        '&output fields = F estimators = F history = F xdmf = F /'//nl// &
                        '&adapt tol = 1.25e-3 theta = 0.30000000000000004 max_steps = 7 max_vertices = 123456 /'//nl)
      call load_config(path, words('problem.f2=1.7976931348623157e308'), cfg, err)
      if (allocated(err)) return
      text = config_echo(cfg)
      do i = 1, size(keys)
         call check(err, index(text, trim(keys(i))) > 0, "echo lacks '"//trim(keys(i))//"':"//nl//text)
      end do
      call check(err, count_lines(text, '/') == 7, 'seven groups closed')
      if (allocated(err)) return

      ! through a file with another name: everything but the source must survive bit for bit
      path2 = write_case('config_echo_copy.nml', text)
      call load_config(path2, [string_t ::], back, err)
      if (allocated(err)) then
         err%message = err%message//nl//text
         return
      end if
      call check(err, config_diff(cfg, back) == '', 'file round trip differs in '//config_diff(cfg, back)//nl//text)
      call check(err, back%problem%f1 == 0 .and. sign(1.0_dp, back%problem%f1) < 0, 'negative zero kept')

      ! in memory, as the result file's attribute would be read
      call load_config_text(text, 'stored', [string_t ::], back2, err)
      if (allocated(err)) return
      call check(err, config_diff(cfg, back2) == '', 'text round trip differs in '//config_diff(cfg, back2))

      ! the defaults echo and reload too
      defaults%output%file = 'results/x.h5'
      call load_config_text(config_echo(defaults), 'x', [string_t ::], back, err)
      if (allocated(err)) return
      call check(err, config_diff(defaults, back) == '', 'default round trip differs in '//config_diff(defaults, back))
      call check(err, index(config_echo(defaults), 'coarse_h = 0.25'//nl) > 0, 'short reals: '//config_echo(defaults))
      call check(err, index(config_echo(defaults), 'tol = 1.0e-10'//nl) > 0, 'exponent form')
   end subroutine test_echo_round_trip

   integer function count_lines(text, line) result(n)
      character(len=*), intent(in) :: text, line

      integer :: start, k

      n = 0
      start = 1
      do while (start <= len(text))
         k = index(text(start:), nl)
         if (k == 0) k = len(text) - start + 2
         if (text(start:start + k - 2) == line) n = n + 1
         start = start + k
      end do
   end function count_lines

   subroutine test_output_file(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      character(len=:), allocatable :: path

      path = write_case('config.case.v2.nml', '&output /')
      call load_config(path, no_overrides(), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%case_name == 'config.case.v2', 'case name drops the last extension: '//trim(cfg%case_name))
      call check(err, cfg%output%file == 'results/config.case.v2.h5', 'default output: '//trim(cfg%output%file))
      call load_config(path, words('output.file=elsewhere/r.h5'), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%output%file == 'elsewhere/r.h5', 'explicit output kept')
      call load_config(path, words("output.file=''"), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%output%file == 'results/config.case.v2.h5', "'' means the default")
   end subroutine test_output_file

   subroutine test_unquoted_path(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg
      character(len=:), allocatable :: path

      ! a '/' inside a bare value is part of it; a '/' followed by a separator ends the group
      path = write_case('config_unquoted.nml', '&mesh domain = gmsh, file = meshes/a.msh levels = 3/'//nl// &
                        '&output file = out/b.h5/'//nl)
      call load_config(path, no_overrides(), cfg, err)
      if (allocated(err)) return
      call check(err, cfg%mesh%file == 'meshes/a.msh', 'unquoted path: '//trim(cfg%mesh%file))
      call check(err, cfg%mesh%levels == 3, "'/' right after a value ends the group")
      call check(err, cfg%output%file == 'out/b.h5', 'path right before the closing slash: '//trim(cfg%output%file))
   end subroutine test_unquoted_path

   subroutine test_value_scanners(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=8), parameter :: bad_reals(12) = [character(len=8) :: '1,2', '1e', 'e5', '1.0.0', '.', '+', &
                                                      '', '1 2', '0x10', '1e+', '--1', '1.0q0']
      character(len=8), parameter :: bad_ints(6) = [character(len=8) :: '1.0', '+', '', '1e3', '--1', '1 2']
      character(len=:), allocatable :: what
      real(dp) :: x
      integer :: i, n
      logical :: b

      do i = 1, size(bad_reals)
         call scan_real(trim(bad_reals(i)), x, what)
         call check(err, allocated(what), "real '"//trim(bad_reals(i))//"' rejected")
      end do
      do i = 1, size(bad_ints)
         call scan_integer(trim(bad_ints(i)), n, what)
         call check(err, allocated(what), "integer '"//trim(bad_ints(i))//"' rejected")
      end do
      call scan_real('-1.5D+2', x, what)
      call check(err, .not. allocated(what) .and. x == -150, 'D exponent')
      call scan_real('.5', x, what)
      call check(err, .not. allocated(what) .and. x == 0.5_dp, 'leading point')
      call scan_real('7.', x, what)
      call check(err, .not. allocated(what) .and. x == 7, 'trailing point')
      call scan_integer('+42', n, what)
      call check(err, .not. allocated(what) .and. n == 42, 'signed integer')
      call scan_integer('-2147483647', n, what)
      call check(err, .not. allocated(what) .and. n == -2147483647, 'large integer')
      call scan_logical('.T.', b, what)
      call check(err, .not. allocated(what) .and. b, '.T.')
      call scan_logical('False', b, what)
      call check(err, .not. allocated(what) .and. .not. b, 'False')
      call scan_logical('tomato', b, what)
      call check(err, allocated(what), 'no word that merely starts with t')
      call check(err, format_real(0.25_dp) == '0.25', '0.25: '//format_real(0.25_dp))
      call check(err, format_real(-3.0_dp) == '-3.0', '-3.0: '//format_real(-3.0_dp))
      call check(err, format_real(1.0e-10_dp) == '1.0e-10', '1e-10: '//format_real(1.0e-10_dp))
      call check(err, format_real(1.5e20_dp) == '1.5e20', '1.5e20: '//format_real(1.5e20_dp))
      call check(err, format_real(100.0_dp) == '100.0', '100: '//format_real(100.0_dp))
   end subroutine test_value_scanners

   !> Random bit patterns over the whole range (subnormals included) print and scan back exactly.
   subroutine test_real_format(err)
      type(error_t), allocatable, intent(out) :: err

      real(dp) :: u(4), x, y
      integer(i8) :: bits
      integer, allocatable :: seed(:)
      character(len=:), allocatable :: what, s
      integer :: i, n

      call random_seed(size=n)
      allocate (seed(n))
      seed = [(7919*i + 1, i=1, n)]
      call random_seed(put=seed)
      do i = 1, 20000
         call random_number(u)
         bits = ior(ishft(int(u(1)*2.0_dp**31, i8), 32), int(u(2)*2.0_dp**32, i8))
         if (u(3) < 0.5_dp) bits = ibset(bits, 63)
         if (u(4) < 0.1_dp) bits = ibclr(ibclr(bits, 62), 61)
         x = transfer(bits, x)
         if (exponent_is_max(bits)) cycle
         s = format_real(x)
         call scan_real(s, y, what)
         call check(err, .not. allocated(what), 'scans: '//s)
         if (allocated(err)) return
         call check(err, same_real(x, y), 'round trip of '//s)
         call check(err, len(s) <= 24, 'short: '//s)
         if (allocated(err)) return
      end do
   end subroutine test_real_format

   !> Infinity and NaN have all exponent bits set; they are not echoed.
   logical function exponent_is_max(bits)
      integer(i8), intent(in) :: bits

      exponent_is_max = iand(ishft(bits, -52), int(z'7FF', i8)) == int(z'7FF', i8)
   end function exponent_is_max
end module test_config
