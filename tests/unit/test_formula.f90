!> Tests of the load formulas: values against the same expressions written in Fortran,
!> precedence and the right-associativity of ^, unary minus, comparisons, every function,
!> constant folding, parse errors with their column, domain errors at evaluation (which must
!> not trap: the debug build traps invalid operations), batches, and the input keys
!> (formula or number, echo, messages) and the load error at a quadrature point.
module test_formula
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: exit_bad_input
   use twomem_input_formula, only: formula_t, status_ok
   use twomem_input_formula_parser, only: parse_formula
   use twomem_input_config, only: config_t, string_t, load_config_text, config_echo
   use twomem_mesh_generators, only: make_square
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_user_data, only: user_data_t, new_user_data
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use twomem_base_text, only: int_text
   implicit none
   private

   public :: collect_formula

   real(dp), parameter :: x0 = 0.3_dp, y0 = -0.4_dp, r0 = 0.5_dp

contains

   subroutine collect_formula(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('arithmetic_and_precedence', test_precedence), &
               new_unittest('power_right_associative', test_power), &
               new_unittest('unary_minus', test_unary), &
               new_unittest('comparisons', test_comparisons), &
               new_unittest('functions', test_functions), &
               new_unittest('constant_folding', test_folding), &
               new_unittest('parse_errors_with_column', test_parse_errors), &
               new_unittest('domain_errors', test_domain_errors), &
               new_unittest('batches', test_batches), &
               new_unittest('input_keys', test_input_keys), &
               new_unittest('nonfinite_load_names_point', test_bad_load_point)]
   end subroutine collect_formula

   !> f(x0, y0) of `text`, which must parse; compared with `expected` to a few ulps.
   subroutine expect(err, text, expected)
      type(error_t), allocatable, intent(inout) :: err
      character(len=*), intent(in) :: text
      real(dp), intent(in) :: expected

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where, status
      real(dp) :: v

      if (allocated(err)) return
      call parse_formula(text, f, where, why)
      if (allocated(why)) then
         call check(err, .false., "'"//text//"' does not parse: column "//int_text(where)//': '//why)
         return
      end if
      call f%evaluate_point([x0, y0], v, status)
      call check(err, status == status_ok, "'"//text//"' fails to evaluate")
      if (allocated(err)) return
      call check_close(err, v, expected, 4*epsilon(1.0_dp), 4*tiny(1.0_dp), "'"//text//"'")
   end subroutine expect

   !> `text` must fail to parse at column `column` with a reason containing `reason`.
   subroutine expect_parse_error(err, text, column, reason)
      type(error_t), allocatable, intent(inout) :: err
      character(len=*), intent(in) :: text, reason
      integer, intent(in) :: column

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where

      if (allocated(err)) return
      call parse_formula(text, f, where, why)
      call check(err, allocated(why), "'"//text//"' parses but must not")
      if (allocated(err)) return
      call check(err, where == column, "'"//text//"': error at column "//int_text(where)//', expected '//int_text(column)// &
                 ' ('//why//')')
      call check(err, index(why, reason) > 0, "'"//text//"': reason '"//why//"' lacks '"//reason//"'")
   end subroutine expect_parse_error

   !> `text` parses but its evaluation at x must fail (and not trap).
   subroutine expect_domain_error(err, text, x)
      type(error_t), allocatable, intent(inout) :: err
      character(len=*), intent(in) :: text
      real(dp), intent(in) :: x(2)

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where, status
      real(dp) :: v

      if (allocated(err)) return
      call parse_formula(text, f, where, why)
      call check(err, .not. allocated(why), "'"//text//"' must parse")
      if (allocated(err)) return
      call f%evaluate_point(x, v, status)
      call check(err, status /= status_ok, "'"//text//"' evaluates without error where it is undefined")
   end subroutine expect_domain_error

   subroutine test_precedence(err)
      type(error_t), allocatable, intent(out) :: err

      call expect(err, '1 + 2*3', 7.0_dp)
      call expect(err, '(1 + 2)*3', 9.0_dp)
      call expect(err, '10 - 4 - 3', 3.0_dp)
      call expect(err, '24/4/3', 2.0_dp)
      call expect(err, '2*x + y/4 - r', 2*x0 + y0/4 - r0)
      call expect(err, 'X + Y', x0 + y0)
      call expect(err, '1.5e-1 + 2.5D0 + .5 + 3.', 0.15_dp + 2.5_dp + 0.5_dp + 3.0_dp)
      call expect(err, 'pi', acos(-1.0_dp))
      call expect(err, '-8*0.05 - 2*0.05*(r <= sqrt(0.5))', -8*0.05_dp - 2*0.05_dp)
   end subroutine test_precedence

   subroutine test_power(err)
      type(error_t), allocatable, intent(out) :: err

      call expect(err, '2^3^2', 512.0_dp)
      call expect(err, '(2^3)^2', 64.0_dp)
      call expect(err, '2**3**2', 512.0_dp)
      call expect(err, '2*3^2', 18.0_dp)
      call expect(err, '2^-1', 0.5_dp)
      call expect(err, '(-2)^3', -8.0_dp)
      call expect(err, 'x^2 + y^2', x0**2 + y0**2)
      call expect(err, 'r^0.5', sqrt(r0))
      call expect(err, '0^0', 1.0_dp)
   end subroutine test_power

   subroutine test_unary(err)
      type(error_t), allocatable, intent(out) :: err

      ! unary minus binds looser than ^: -2^2 = -(2^2), as in mathematics
      call expect(err, '-2^2', -4.0_dp)
      call expect(err, '--2', 2.0_dp)
      call expect(err, '+-+2', -2.0_dp)
      call expect(err, '3 - -2', 5.0_dp)
      call expect(err, '-x*y', -x0*y0)
      call expect(err, '2*-x', -2*x0)
   end subroutine test_unary

   subroutine test_comparisons(err)
      type(error_t), allocatable, intent(out) :: err

      call expect(err, 'x < y', 0.0_dp)
      call expect(err, 'x > y', 1.0_dp)
      call expect(err, 'x <= 0.3', 1.0_dp)
      call expect(err, 'x >= 0.31', 0.0_dp)
      call expect(err, 'r == 0.5', 1.0_dp)
      call expect(err, 'r != 0.5', 0.0_dp)
      call expect(err, 'r /= 1', 1.0_dp)
      ! a comparison has the lowest precedence: 1 + 2 < 2 + 2 is (1 + 2) < (2 + 2)
      call expect(err, '1 + 2 < 2 + 2', 1.0_dp)
      call expect(err, '(x < 1) + (y < 1)', 2.0_dp)
      call expect(err, '3*(r <= sqrt(0.5)) - 1', 2.0_dp)
   end subroutine test_comparisons

   subroutine test_functions(err)
      type(error_t), allocatable, intent(out) :: err

      call expect(err, 'sqrt(x)', sqrt(x0))
      call expect(err, 'exp(y)', exp(y0))
      call expect(err, 'log(x)', log(x0))
      call expect(err, 'sin(x)', sin(x0))
      call expect(err, 'cos(y)', cos(y0))
      call expect(err, 'tan(x)', tan(x0))
      call expect(err, 'atan2(y, x)', atan2(y0, x0))
      call expect(err, 'abs(y)', abs(y0))
      call expect(err, 'min(x, y)', min(x0, y0))
      call expect(err, 'max(x, y)', max(x0, y0))
      call expect(err, 'max(x, y, r, -1)', r0)
      call expect(err, 'min(1, 2, y)', y0)
      call expect(err, 'SQRT(ABS(y))*Exp(0)', sqrt(abs(y0)))
      call expect(err, 'sin(pi/2)^2 + cos(0)', 2.0_dp)
   end subroutine test_functions

   !> Subexpressions without x, y, r become one constant.
   subroutine test_folding(err)
      type(error_t), allocatable, intent(out) :: err

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where

      call parse_formula('-8*0.05 - 2*0.05*sqrt(0.5)^2', f, where, why)
      call check(err, .not. allocated(why), 'parses')
      if (allocated(err)) return
      call check(err, f%constant .and. f%n == 1, 'a formula without x, y, r is one constant')
      call parse_formula('x*(2 + 3) + sqrt(4)', f, where, why)
      call check(err, f%n == 5, 'x*(2 + 3) + sqrt(4): x, 5, *, 2, + (got '//int_text(f%n)//' instructions)')
   end subroutine test_folding

   subroutine test_parse_errors(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_parse_error(err, '', 1, 'empty formula')
      call expect_parse_error(err, '   ', 4, 'empty formula')
      call expect_parse_error(err, '1 +', 4, 'expression expected')
      call expect_parse_error(err, '2*z', 3, "unknown name 'z'")
      call expect_parse_error(err, 'x y', 3, "unexpected 'y'")
      call expect_parse_error(err, '(x + 1', 1, "'(' is never closed")
      call expect_parse_error(err, 'x + 1)', 6, "unexpected ')'")
      call expect_parse_error(err, 'sqrt x', 6, "expected '(' after 'sqrt'")
      call expect_parse_error(err, 'sqrt(1, 2)', 1, "'sqrt' takes exactly")
      call expect_parse_error(err, 'atan2(1)', 1, "'atan2' takes exactly")
      call expect_parse_error(err, 'max(1)', 1, "'max' takes at least")
      call expect_parse_error(err, 'min(1; 2)', 6, "expected ',' or ')'")
      call expect_parse_error(err, 'x # 2', 3, "unexpected '#'")
      call expect_parse_error(err, '1e', 1, 'exponent of the number has no digits')
      call expect_parse_error(err, '1e999', 1, 'not a finite number')
      call expect_parse_error(err, 'x < y < 1', 3, 'comparisons do not chain')
      call expect_parse_error(err, 'log(0) + x', 1, 'log of a number <= 0')
      call expect_parse_error(err, 'x + 1/0', 6, 'division by zero')
      call expect_parse_error(err, 'x = 1', 3, "unexpected '='")
      call expect_parse_error(err, 'foo(x)', 1, "unknown name 'foo'")
   end subroutine test_parse_errors

   subroutine test_domain_errors(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_domain_error(err, 'log(x)', [-1.0_dp, 0.0_dp])
      call expect_domain_error(err, 'log(x)', [0.0_dp, 1.0_dp])
      call expect_domain_error(err, 'sqrt(y)', [0.0_dp, -1.0_dp])
      call expect_domain_error(err, '1/x', [0.0_dp, 1.0_dp])
      call expect_domain_error(err, 'x^0.5', [-1.0_dp, 0.0_dp])
      call expect_domain_error(err, 'x^-1', [0.0_dp, 0.0_dp])
      call expect_domain_error(err, 'atan2(y, x)', [0.0_dp, 0.0_dp])
      call expect_domain_error(err, 'exp(1000*x)', [1.0_dp, 0.0_dp])
      call expect_domain_error(err, '1e300*x*1e300', [1.0_dp, 0.0_dp])
      call expect_domain_error(err, '1e308*x + 1e308', [1.0_dp, 0.0_dp])
      call expect_domain_error(err, '(10*x)^400', [1.0_dp, 0.0_dp])
      call expect_domain_error(err, '1/(x*1e-200)^2', [1.0e-200_dp, 0.0_dp])
      ! and where they are defined, they are
      call expect(err, 'exp(-1000*x)', exp(-300.0_dp))
      call expect(err, '(x/10)^400', 0.0_dp)
   end subroutine test_domain_errors

   !> Batches longer than the machine's internal batch, and the failing point's index.
   subroutine test_batches(err)
      type(error_t), allocatable, intent(out) :: err

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where, status, bad, k
      real(dp) :: x(2, 37), v(37)

      call parse_formula('x*x - 2*y + (r > 3)', f, where, why)
      do k = 1, 37
         x(:, k) = [0.1_dp*k, -0.05_dp*k]
      end do
      call f%evaluate(x, v, status, bad)
      call check(err, status == status_ok .and. bad == 0, 'evaluates')
      if (allocated(err)) return
      do k = 1, 37
         call check_close(err, v(k), x(1, k)**2 - 2*x(2, k) + merge(1.0_dp, 0.0_dp, norm2(x(:, k)) > 3), &
                          4*epsilon(1.0_dp), 1.0e-300_dp, 'point '//int_text(k))
      end do
      ! x = 0.1 k, so log(2.05 − x) fails first at k = 21, in the second internal batch
      call parse_formula('log(2.05 - x)', f, where, why)
      call f%evaluate(x, v, status, bad)
      call check(err, status /= status_ok .and. bad == 21, 'first failing point 21 (x = 2.1), got '//int_text(bad))
   end subroutine test_batches

   !> f1, f2 take a number or a formula, in a file (quoted) or an override (quoted or not);
   !> the echo keeps the formula; errors name the key and the column.
   subroutine test_input_keys(err)
      type(error_t), allocatable, intent(out) :: err

      type(config_t) :: cfg, again
      type(error_t), allocatable :: got
      character(len=*), parameter :: base = '&problem'//new_line('a')//"  f1 = '-0.4 - 0.1*(r <= sqrt(0.5))'"// &
                                            new_line('a')//'  f2 = 0.25'//new_line('a')//'/'//new_line('a')

      call load_config_text(base, 'case.nml', [string_t :: ], cfg, got)
      call check(err, .not. allocated(got), 'a quoted formula is accepted')
      if (allocated(err)) return
      call check(err, trim(cfg%problem%f1_formula) == '-0.4 - 0.1*(r <= sqrt(0.5))', 'f1 is kept as a formula')
      call check(err, len_trim(cfg%problem%f2_formula) == 0 .and. cfg%problem%f2 == 0.25_dp, 'f2 stays a number')
      call load_config_text(config_echo(cfg), 'echo.nml', [string_t :: ], again, got)
      call check(err, .not. allocated(got), 'the echo reloads')
      if (allocated(err)) return
      call check(err, again%problem%f1_formula == cfg%problem%f1_formula, 'the echo keeps the formula')

      call load_config_text(base, 'case.nml', words('problem.f2=2*x+1', "problem.f1='-0.5'"), cfg, got)
      call check(err, .not. allocated(got), 'overrides with a bare formula and a quoted number')
      if (allocated(err)) return
      call check(err, trim(cfg%problem%f2_formula) == '2*x+1', 'a bare override that is no number is a formula')
      call check(err, len_trim(cfg%problem%f1_formula) == 0 .and. cfg%problem%f1 == -0.5_dp, &
                 'a quoted number is a number')

      call load_config_text(base, 'case.nml', words('problem.f2=2*x+q'), cfg, got)
      call check(err, allocated(got), 'an unknown name is refused')
      if (allocated(err)) return
      call check(err, got%code == exit_bad_input, 'bad input')
      call check(err, index(got%message, "override 'problem.f2=2*x+q': &problem: f2 formula '2*x+q': column 5: "// &
                            "unknown name 'q'") > 0, 'message: '//got%message)

      call load_config_text(base, 'case.nml', words("problem.exact='radial'"), cfg, got)
      call check(err, allocated(got), 'radial with a formula load is refused')
      if (allocated(err)) return
      call check(err, index(got%message, "exact='radial' has its own loads") > 0, 'message: '//got%message)

      call load_config_text(base, 'case.nml', words('problem.f1_file=loads.h5'), cfg, got)
      call check(err, allocated(got), 'f1_file without a dataset is refused')
      if (allocated(err)) return
      call check(err, index(got%message, "f1_file must be 'FILE:DATASET'") > 0, 'message: '//got%message)

      call load_config_text(base, 'case.nml', words('problem.f1_file=loads.h5:/f1'), cfg, got)
      call check(err, allocated(got), 'f1_file with an f1 formula is refused')
      if (allocated(err)) return
      call check(err, index(got%message, 'f1_file and a formula for f1 are both given') > 0, 'message: '//got%message)
   end subroutine test_input_keys

   !> log(x) on the square (−1,1)²: the discrete problem refuses it, naming a quadrature point
   !> with x < 0 and the reason.
   subroutine test_bad_load_point(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh
      type(user_data_t) :: data
      type(discrete_problem_t) :: p
      type(error_t), allocatable :: got
      real(dp) :: x, y
      integer :: at, ios

      call make_square(0.5_dp, mesh, err)
      if (allocated(err)) return
      call new_user_data(1.0_dp, 1.0_dp, 0.05_dp, [0.0_dp, 0.0_dp], [character(len=8) :: '', 'log(x)'], data, err)
      if (allocated(err)) return
      call p%init(mesh, data, got)
      call check(err, allocated(got), 'log(x) on (-1,1)^2 is refused')
      if (allocated(err)) return
      call check(err, got%code == exit_bad_input, 'bad input')
      call check(err, index(got%message, 'problem.f2: not finite at the quadrature point (x, y) = (') == 1, &
                 'message names the load and the point: '//got%message)
      call check(err, index(got%message, "formula 'log(x)': log of a number <= 0") > 0, 'and the reason: '//got%message)
      if (allocated(err)) return
      at = index(got%message, '= (') + 3
      read (got%message(at:at - 1 + index(got%message(at:), ')') - 1), *, iostat=ios) x, y
      call check(err, ios == 0, 'the point reads back: '//got%message(at:))
      if (allocated(err)) return
      call check(err, x <= 0 .and. abs(x) < 1 .and. abs(y) < 1, 'the point lies in the square where x <= 0')
   end subroutine test_bad_load_point
   !> Overrides as string_t values, filled component by component: gfortran 12 leaks the
   !> components of a string_t array constructor (LeakSanitizer in the sanitize preset).
   function words(a, b) result(o)
      character(len=*), intent(in) :: a
      character(len=*), intent(in), optional :: b
      type(string_t), allocatable :: o(:)

      allocate (o(merge(2, 1, present(b))))
      o(1)%s = a
      if (present(b)) o(2)%s = b
   end function words
end module test_formula
