!> Formulas of position for user data such as `problem.f1 = '-0.4 - 0.1*(r <= sqrt(0.5))'`:
!> parsed once, by recursive descent, into a postfix instruction list that a small stack
!> machine evaluates at many points. Evaluation must be cheap (it runs at every quadrature
!> point of every assembly) and must never raise a floating-point exception (debug builds trap
!> them): every operation checks its domain first, so every value on the stack stays finite,
!> and a violation stops the evaluation with a status whose reason `formula_status_text` names.
!> Constant subexpressions are folded while parsing, so `sqrt(0.5)` costs nothing per point.
module twomem_input_formula
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp
   use twomem_input_values, only: scan_real
   implicit none
   private

   public :: formula_t, parse_formula, formula_status_text, status_ok

   !> the deepest stack a formula may need; deeper nesting is a parse error
   integer, parameter :: max_depth = 48
   !> points evaluated together: one instruction dispatch serves this many points
   integer, parameter :: batch = 16

   integer, parameter :: op_const = 1, op_x = 2, op_y = 3, op_r = 4, op_add = 5, op_sub = 6, &
      op_mul = 7, op_div = 8, op_pow = 9, op_neg = 10, op_lt = 11, op_le = 12, op_gt = 13, op_ge = 14, &
      op_eq = 15, op_ne = 16, op_sqrt = 17, op_exp = 18, op_log = 19, op_sin = 20, op_cos = 21, &
      op_tan = 22, op_atan2 = 23, op_abs = 24, op_min = 25, op_max = 26, op_square = 27

   integer, parameter :: status_ok = 0, status_div_zero = 1, status_overflow = 2, status_log = 3, &
      status_sqrt = 4, status_pow = 5, status_atan2 = 6

   !> A parsed formula: `op(i)` with its constant `value(i)` (op_const only), in postfix order.
   type :: formula_t
      character(len=:), allocatable :: text
      integer, allocatable :: op(:)
      real(dp), allocatable :: value(:)
      integer :: n = 0
      !> the formula does not depend on the position: it is `value(1)`
      logical :: constant = .false.
      !> r appears: computed once per batch of points
      logical :: uses_r = .false.
   contains
      procedure :: evaluate
      procedure :: evaluate_point
   end type formula_t

   !> The parser's state: the text, the position of the next character, the code emitted so
   !> far with the stack depth it needs, and the first error (position and reason).
   type :: parser_t
      character(len=:), allocatable :: s
      integer :: pos = 1
      integer, allocatable :: op(:)
      real(dp), allocatable :: value(:)
      integer :: n = 0, depth = 0, max_seen = 0
      integer :: err_pos = 0
      character(len=:), allocatable :: err
   end type parser_t

contains

   !> Parse `text`. On failure `where` is the 1-based column of the problem and `why` the reason;
   !> on success `why` is not allocated.
   subroutine parse_formula(text, f, where, why)
      character(len=*), intent(in) :: text
      type(formula_t), intent(out) :: f
      integer, intent(out) :: where
      character(len=:), allocatable, intent(out) :: why

      type(parser_t) :: p

      where = 0
      p%s = text
      allocate (p%op(16), p%value(16))
      call skip_blanks(p)
      if (p%pos > len(p%s)) then
         call fail(p, 'empty formula')
      else
         call parse_comparison(p)
         if (.not. allocated(p%err)) then
            call skip_blanks(p)
            if (p%pos <= len(p%s)) call fail(p, "unexpected '"//p%s(p%pos:p%pos)//"' after a complete expression")
         end if
      end if
      if (allocated(p%err)) then
         where = p%err_pos
         call move_alloc(p%err, why)
         return
      end if
      f%text = text
      f%n = p%n
      f%op = p%op(1:p%n)
      f%value = p%value(1:p%n)
      f%constant = p%n == 1 .and. p%op(1) == op_const
      f%uses_r = any(f%op == op_r)
   end subroutine parse_formula

   !> The reason of an evaluation status, for messages.
   pure function formula_status_text(status) result(s)
      integer, intent(in) :: status
      character(len=:), allocatable :: s

      select case (status)
      case (status_ok); s = 'no error'
      case (status_div_zero); s = 'division by zero'
      case (status_overflow); s = 'the value overflows'
      case (status_log); s = 'log of a number <= 0'
      case (status_sqrt); s = 'sqrt of a negative number'
      case (status_pow); s = 'power undefined (negative base with a non-integer exponent, or 0 to a negative power)'
      case (status_atan2); s = 'atan2(0, 0)'
      case default; s = 'unknown error'
      end select
   end function formula_status_text

   ! ---- evaluation ------------------------------------------------------------------------

   !> values(k) = f(x(:, k)); status is status_ok, or the first failure (its point: bad).
   pure subroutine evaluate(self, x, values, status, bad)
      class(formula_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: values(:)
      integer, intent(out) :: status
      !> index of the point where the evaluation failed (0 when status_ok)
      integer, intent(out) :: bad

      integer :: first, m

      status = status_ok
      bad = 0
      if (self%constant) then
         values = self%value(1)
         return
      end if
      do first = 1, size(x, 2), batch
         m = min(batch, size(x, 2) - first + 1)
         call run(self, x(:, first:first + m - 1), m, values(first:first + m - 1), status, bad)
         if (status /= status_ok) then
            bad = bad + first - 1
            return
         end if
      end do
   end subroutine evaluate

   !> f at one point (status as in `evaluate`).
   pure subroutine evaluate_point(self, x, value, status)
      class(formula_t), intent(in) :: self
      real(dp), intent(in) :: x(2)
      real(dp), intent(out) :: value
      integer, intent(out) :: status

      real(dp) :: v(1)
      integer :: bad

      call self%evaluate(reshape(x, [2, 1]), v, status, bad)
      value = v(1)
   end subroutine evaluate_point

   !> The stack machine on up to `batch` points at once: s(:, d) is stack level d for every point.
   pure subroutine run(self, x, m, values, status, bad)
      type(formula_t), intent(in) :: self
      integer, intent(in) :: m
      !> assumed shape: the caller's strided sections pass without copies
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: values(:)
      integer, intent(inout) :: status, bad

      real(dp), parameter :: big = huge(1.0_dp)
      real(dp) :: s(batch, max_depth), r(batch)
      integer :: i, d

      if (self%uses_r) r(1:m) = sqrt(x(1, 1:m)**2 + x(2, 1:m)**2)
      d = 0
      do i = 1, self%n
         select case (self%op(i))
         case (op_const)
            d = d + 1
            s(1:m, d) = self%value(i)
         case (op_x)
            d = d + 1
            s(1:m, d) = x(1, 1:m)
         case (op_y)
            d = d + 1
            s(1:m, d) = x(2, 1:m)
         case (op_r)
            d = d + 1
            s(1:m, d) = r(1:m)
         case (op_neg)
            s(1:m, d) = -s(1:m, d)
         case (op_abs)
            s(1:m, d) = abs(s(1:m, d))
         case (op_sin)
            s(1:m, d) = sin(s(1:m, d))
         case (op_cos)
            s(1:m, d) = cos(s(1:m, d))
         case (op_min)
            d = d - 1
            s(1:m, d) = min(s(1:m, d), s(1:m, d + 1))
         case (op_max)
            d = d - 1
            s(1:m, d) = max(s(1:m, d), s(1:m, d + 1))
         case (op_lt)
            d = d - 1
            s(1:m, d) = merge(1.0_dp, 0.0_dp, s(1:m, d) < s(1:m, d + 1))
         case (op_le)
            d = d - 1
            s(1:m, d) = merge(1.0_dp, 0.0_dp, s(1:m, d) <= s(1:m, d + 1))
         case (op_gt)
            d = d - 1
            s(1:m, d) = merge(1.0_dp, 0.0_dp, s(1:m, d) > s(1:m, d + 1))
         case (op_ge)
            d = d - 1
            s(1:m, d) = merge(1.0_dp, 0.0_dp, s(1:m, d) >= s(1:m, d + 1))
         case (op_eq)
            d = d - 1
            s(1:m, d) = merge(1.0_dp, 0.0_dp, s(1:m, d) == s(1:m, d + 1))
         case (op_ne)
            d = d - 1
            s(1:m, d) = merge(1.0_dp, 0.0_dp, s(1:m, d) /= s(1:m, d + 1))
         ! +, −, *, / on the whole batch when a test that cannot itself overflow shows that no
         ! point can overflow (almost always); otherwise point by point, which finds the point
         case (op_add)
            d = d - 1
            if (all(abs(s(1:m, d)) <= big - abs(s(1:m, d + 1)))) then
               s(1:m, d) = s(1:m, d) + s(1:m, d + 1)
            else
               call careful(op_add, 2, s, d, m, status, bad)
            end if
         case (op_sub)
            d = d - 1
            if (all(abs(s(1:m, d)) <= big - abs(s(1:m, d + 1)))) then
               s(1:m, d) = s(1:m, d) - s(1:m, d + 1)
            else
               call careful(op_sub, 2, s, d, m, status, bad)
            end if
         case (op_mul)
            d = d - 1
            if (all(abs(s(1:m, d + 1)) <= big/max(abs(s(1:m, d)), 1.0_dp))) then
               s(1:m, d) = s(1:m, d)*s(1:m, d + 1)
            else
               call careful(op_mul, 2, s, d, m, status, bad)
            end if
         case (op_div)
            d = d - 1
            if (all(abs(s(1:m, d)) < big*min(abs(s(1:m, d + 1)), 1.0_dp))) then
               s(1:m, d) = s(1:m, d)/s(1:m, d + 1)
            else
               call careful(op_div, 2, s, d, m, status, bad)
            end if
         case (op_square)
            if (all(abs(s(1:m, d)) <= sqrt(big))) then
               s(1:m, d) = s(1:m, d)**2
            else
               call careful(op_square, 1, s, d, m, status, bad)
            end if
         case default
            ! the operations with a domain: one point at a time
            if (is_binary(self%op(i))) d = d - 1
            call careful(self%op(i), merge(2, 1, is_binary(self%op(i))), s, d, m, status, bad)
         end select
         if (status /= status_ok) then
            values = 0.0_dp
            return
         end if
      end do
      values(1:m) = s(1:m, 1)
   end subroutine run

   !> Operation `op` of `arity` on stack level d of the first m points of s, point by point with
   !> every domain check; on failure `bad` is the point.
   pure subroutine careful(op, arity, s, d, m, status, bad)
      integer, intent(in) :: op, arity, d, m
      real(dp), intent(inout) :: s(:, :)
      integer, intent(inout) :: status, bad

      real(dp) :: a, b, c
      integer :: k

      do k = 1, m
         a = s(k, d)
         b = 0.0_dp
         if (arity == 2) b = s(k, d + 1)
         if (op == op_square) then
            call apply(op_mul, a, a, c, status)
         else
            call apply(op, a, b, c, status)
         end if
         if (status /= status_ok) then
            bad = k
            return
         end if
         s(k, d) = c
      end do
   end subroutine careful

   pure logical function is_binary(op)
      integer, intent(in) :: op

      select case (op)
      case (op_add, op_sub, op_mul, op_div, op_pow, op_atan2, op_min, op_max, op_lt, op_le, op_gt, op_ge, &
            op_eq, op_ne)
         is_binary = .true.
      case default
         is_binary = .false.
      end select
   end function is_binary

   pure real(dp) function compare(op, a, b)
      integer, intent(in) :: op
      real(dp), intent(in) :: a, b

      logical :: t

      select case (op)
      case (op_lt); t = a < b
      case (op_le); t = a <= b
      case (op_gt); t = a > b
      case (op_ge); t = a >= b
      case (op_eq); t = a == b
      case default; t = a /= b
      end select
      compare = merge(1.0_dp, 0.0_dp, t)
   end function compare

   !> c = a op b (b unused by unary operations) for finite a, b; c is finite when status_ok.
   pure subroutine apply(op, a, b, c, status)
      integer, intent(in) :: op
      real(dp), intent(in) :: a, b
      real(dp), intent(out) :: c
      integer, intent(out) :: status

      real(dp), parameter :: big = huge(1.0_dp), log_big = log(huge(1.0_dp))
      real(dp) :: t

      status = status_ok
      c = 0.0_dp
      select case (op)
      ! Fortran does not short-circuit .and.: every guard below must be safe to evaluate on
      ! its own, hence the nesting
      case (op_add, op_sub)
         t = merge(b, -b, op == op_add)
         ! only same signs can overflow, and then big − |t| cannot
         if (sign(1.0_dp, a) == sign(1.0_dp, t)) then
            if (abs(a) > big - abs(t)) status = status_overflow
         end if
         if (status == status_ok) c = a + t
      case (op_mul)
         if (abs(a) > 1) then
            if (abs(b) > big/abs(a)) status = status_overflow
         end if
         if (status == status_ok) c = a*b
      case (op_div)
         if (b == 0) then
            status = status_div_zero
         else if (abs(b) < 1) then
            if (abs(a) > big*abs(b)) then
               status = status_overflow
            else
               c = a/b
            end if
         else
            c = a/b
         end if
      case (op_pow)
         call power(a, b, c, status)
      case (op_sqrt)
         if (a < 0) then
            status = status_sqrt
         else
            c = sqrt(a)
         end if
      case (op_exp)
         if (a > log_big) then
            status = status_overflow
         else
            c = exp(a)
         end if
      case (op_log)
         if (a <= 0) then
            status = status_log
         else
            c = log(a)
         end if
      case (op_tan)
         c = tan(a)
         if (.not. ieee_is_finite(c)) status = status_overflow
      case (op_atan2)
         ! atan2(y, x): a is y, b is x
         if (a == 0 .and. b == 0) then
            status = status_atan2
         else
            c = atan2(a, b)
         end if
      end select
   end subroutine apply

   !> a^b for finite a, b: integer exponents for any base, real exponents for positive bases.
   pure subroutine power(a, b, c, status)
      real(dp), intent(in) :: a, b
      real(dp), intent(out) :: c
      integer, intent(out) :: status

      real(dp), parameter :: log_big = log(huge(1.0_dp))
      real(dp) :: l
      logical :: whole

      status = status_ok
      c = 0.0_dp
      whole = abs(b) < 2.0_dp**52 .and. b == aint(b)
      if (a == 0) then
         if (b < 0) then
            status = status_pow
         else if (b == 0) then
            c = 1.0_dp
         end if
         return
      end if
      if (a < 0 .and. .not. whole) then
         status = status_pow
         return
      end if
      ! |a|^b = exp(b log|a|): overflow is known before computing it
      l = log(abs(a))
      if (abs(b) > 1) then
         if (abs(l) > log_big/abs(b)) then
            if (b*sign(1.0_dp, l) > 0) then
               status = status_overflow
               return
            end if
            ! underflows to 0 (no trap)
            c = 0.0_dp
            return
         end if
      end if
      if (b*l > log_big) then
         status = status_overflow
         return
      end if
      if (whole .and. abs(b) < 2.0_dp**31) then
         c = a**int(b)
      else
         c = a**b
      end if
   end subroutine power

   ! ---- parsing ---------------------------------------------------------------------------
   ! comparison := sum [ ('<' | '<=' | '>' | '>=' | '==' | '!=' | '/=') sum ]
   ! sum        := term { ('+' | '-') term }
   ! term       := unary { ('*' | '/') unary }
   ! unary      := ('-' | '+') unary | power
   ! power      := primary [ ('^' | '**') unary ]          (right-associative: 2^3^2 = 2^9)
   ! primary    := number | x | y | r | pi | name '(' comparison { ',' comparison } ')'
   !             | '(' comparison ')'

   recursive subroutine parse_comparison(p)
      type(parser_t), intent(inout) :: p

      integer :: op, at

      call parse_sum(p)
      if (allocated(p%err)) return
      call skip_blanks(p)
      at = p%pos
      op = comparison_op(p)
      if (op == 0) return
      call parse_sum(p)
      if (allocated(p%err)) return
      call emit(p, op)
      if (allocated(p%err)) return
      call skip_blanks(p)
      if (comparison_op(p) /= 0) call fail_at(p, at, 'comparisons do not chain: use parentheses, e.g. (a < b) < c')
   end subroutine parse_comparison

   !> The comparison operator at the position (consumed), or 0.
   integer function comparison_op(p) result(op)
      type(parser_t), intent(inout) :: p

      character(len=2) :: two

      op = 0
      if (p%pos > len(p%s)) return
      two = p%s(p%pos:min(p%pos + 1, len(p%s)))
      select case (two)
      case ('<='); op = op_le
      case ('>='); op = op_ge
      case ('=='); op = op_eq
      case ('!=', '/='); op = op_ne
      end select
      if (op /= 0) then
         p%pos = p%pos + 2
         return
      end if
      select case (two(1:1))
      case ('<'); op = op_lt
      case ('>'); op = op_gt
      end select
      if (op /= 0) p%pos = p%pos + 1
   end function comparison_op

   recursive subroutine parse_sum(p)
      type(parser_t), intent(inout) :: p

      character :: c
      integer :: at

      call parse_term(p)
      do while (.not. allocated(p%err))
         call skip_blanks(p)
         if (p%pos > len(p%s)) return
         c = p%s(p%pos:p%pos)
         if (c /= '+' .and. c /= '-') return
         at = p%pos
         p%pos = p%pos + 1
         call parse_term(p)
         if (allocated(p%err)) return
         call emit(p, merge(op_add, op_sub, c == '+'), at)
      end do
   end subroutine parse_sum

   recursive subroutine parse_term(p)
      type(parser_t), intent(inout) :: p

      character :: c
      integer :: at

      call parse_unary(p)
      do while (.not. allocated(p%err))
         call skip_blanks(p)
         if (p%pos > len(p%s)) return
         c = p%s(p%pos:p%pos)
         if (c == '*' .and. p%pos < len(p%s)) then
            ! '**' is the power operator, handled below
            if (p%s(p%pos + 1:p%pos + 1) == '*') return
         end if
         if (c /= '*' .and. c /= '/') return
         ! '/=' is a comparison
         if (c == '/' .and. p%pos < len(p%s)) then
            if (p%s(p%pos + 1:p%pos + 1) == '=') return
         end if
         at = p%pos
         p%pos = p%pos + 1
         call parse_unary(p)
         if (allocated(p%err)) return
         call emit(p, merge(op_mul, op_div, c == '*'), at)
      end do
   end subroutine parse_term

   recursive subroutine parse_unary(p)
      type(parser_t), intent(inout) :: p

      character :: c

      call skip_blanks(p)
      if (p%pos > len(p%s)) then
         call fail(p, 'expression expected at the end of the formula')
         return
      end if
      c = p%s(p%pos:p%pos)
      if (c == '-' .or. c == '+') then
         p%pos = p%pos + 1
         call parse_unary(p)
         if (allocated(p%err)) return
         if (c == '-') call emit(p, op_neg)
         return
      end if
      call parse_power(p)
   end subroutine parse_unary

   recursive subroutine parse_power(p)
      type(parser_t), intent(inout) :: p

      integer :: at

      call parse_primary(p)
      if (allocated(p%err)) return
      call skip_blanks(p)
      if (p%pos > len(p%s)) return
      at = p%pos
      if (p%s(p%pos:p%pos) == '^') then
         p%pos = p%pos + 1
      else if (p%pos < len(p%s) .and. p%s(p%pos:min(p%pos + 1, len(p%s))) == '**') then
         p%pos = p%pos + 2
      else
         return
      end if
      ! the exponent is a unary: 2^-1 works, and 2^3^2 recurses to the right
      call parse_unary(p)
      if (allocated(p%err)) return
      call emit(p, op_pow, at)
   end subroutine parse_power

   recursive subroutine parse_primary(p)
      type(parser_t), intent(inout) :: p

      character :: c
      integer :: start, op, nargs, need
      character(len=:), allocatable :: name

      call skip_blanks(p)
      if (p%pos > len(p%s)) then
         call fail(p, 'expression expected at the end of the formula')
         return
      end if
      c = p%s(p%pos:p%pos)
      if (c == '(') then
         start = p%pos
         p%pos = p%pos + 1
         call parse_comparison(p)
         if (allocated(p%err)) return
         call skip_blanks(p)
         if (p%pos > len(p%s)) then
            call fail_at(p, start, "'(' is never closed")
         else if (p%s(p%pos:p%pos) /= ')') then
            call fail(p, "expected ')', found '"//p%s(p%pos:p%pos)//"'")
         else
            p%pos = p%pos + 1
         end if
         return
      end if
      if (is_digit(c) .or. c == '.') then
         call parse_number(p)
         return
      end if
      if (.not. is_letter(c)) then
         call fail(p, "unexpected '"//c//"': expected a number, a name or '('")
         return
      end if
      start = p%pos
      do while (p%pos <= len(p%s))
         c = p%s(p%pos:p%pos)
         if (.not. (is_letter(c) .or. is_digit(c) .or. c == '_')) exit
         p%pos = p%pos + 1
      end do
      name = lower(p%s(start:p%pos - 1))
      select case (name)
      case ('x'); call emit(p, op_x); return
      case ('y'); call emit(p, op_y); return
      case ('r'); call emit(p, op_r); return
      case ('pi'); call emit_const(p, acos(-1.0_dp)); return
      case ('sqrt'); op = op_sqrt; need = 1
      case ('exp'); op = op_exp; need = 1
      case ('log'); op = op_log; need = 1
      case ('sin'); op = op_sin; need = 1
      case ('cos'); op = op_cos; need = 1
      case ('tan'); op = op_tan; need = 1
      case ('abs'); op = op_abs; need = 1
      case ('atan2'); op = op_atan2; need = 2
      case ('min'); op = op_min; need = -2
      case ('max'); op = op_max; need = -2
      case default
         call fail_at(p, start, "unknown name '"//name//"' (variables: x, y, r, pi; functions: sqrt, exp, log, "// &
                      'sin, cos, tan, atan2, abs, min, max)')
         return
      end select
      call skip_blanks(p)
      if (p%pos > len(p%s)) then
         call fail(p, "expected '(' after '"//name//"'")
         return
      end if
      if (p%s(p%pos:p%pos) /= '(') then
         call fail(p, "expected '(' after '"//name//"'")
         return
      end if
      p%pos = p%pos + 1
      nargs = 0
      do
         call parse_comparison(p)
         if (allocated(p%err)) return
         nargs = nargs + 1
         ! min and max of more than two arguments fold pairwise
         if ((op == op_min .or. op == op_max) .and. nargs >= 2) call emit(p, op)
         if (allocated(p%err)) return
         call skip_blanks(p)
         if (p%pos > len(p%s)) then
            call fail(p, "expected ')' to close the arguments of '"//name//"'")
            return
         end if
         c = p%s(p%pos:p%pos)
         p%pos = p%pos + 1
         if (c == ')') exit
         if (c /= ',') then
            call fail_at(p, p%pos - 1, "expected ',' or ')' in the arguments of '"//name//"', found '"//c//"'")
            return
         end if
      end do
      if ((need > 0 .and. nargs /= need) .or. (need < 0 .and. nargs < -need)) then
         call fail_at(p, start, "'"//name//"' takes "//merge('exactly  ', 'at least ', need > 0)// &
                      char(48 + abs(need))//' argument'//merge('s', ' ', abs(need) > 1))
         return
      end if
      if (op /= op_min .and. op /= op_max) call emit(p, op, start)
   end subroutine parse_primary

   subroutine parse_number(p)
      type(parser_t), intent(inout) :: p

      integer :: start
      real(dp) :: v
      character :: c
      logical :: digits
      character(len=:), allocatable :: what

      start = p%pos
      digits = .false.
      do while (p%pos <= len(p%s))
         c = p%s(p%pos:p%pos)
         if (.not. is_digit(c)) exit
         digits = .true.
         p%pos = p%pos + 1
      end do
      if (p%pos <= len(p%s)) then
         if (p%s(p%pos:p%pos) == '.') then
            p%pos = p%pos + 1
            do while (p%pos <= len(p%s))
               if (.not. is_digit(p%s(p%pos:p%pos))) exit
               digits = .true.
               p%pos = p%pos + 1
            end do
         end if
      end if
      if (.not. digits) then
         call fail_at(p, start, "'.' is not a number")
         return
      end if
      if (p%pos <= len(p%s)) then
         if (index('eEdD', p%s(p%pos:p%pos)) > 0) then
            p%pos = p%pos + 1
            if (p%pos <= len(p%s)) then
               if (index('+-', p%s(p%pos:p%pos)) > 0) p%pos = p%pos + 1
            end if
            if (p%pos > len(p%s)) then
               call fail_at(p, start, 'the exponent of the number has no digits')
               return
            end if
            if (.not. is_digit(p%s(p%pos:p%pos))) then
               call fail_at(p, start, 'the exponent of the number has no digits')
               return
            end if
            do while (p%pos <= len(p%s))
               if (.not. is_digit(p%s(p%pos:p%pos))) exit
               p%pos = p%pos + 1
            end do
         end if
      end if
      ! scan_real reads without trapping on overflow (1e999)
      call scan_real(p%s(start:p%pos - 1), v, what)
      if (allocated(what)) then
         call fail_at(p, start, "'"//p%s(start:p%pos - 1)//"' is not a finite number")
         return
      end if
      call emit_const(p, v)
   end subroutine parse_number

   subroutine emit_const(p, v)
      type(parser_t), intent(inout) :: p
      real(dp), intent(in) :: v

      call push(p, op_const, v)
      p%depth = p%depth + 1
      call track_depth(p)
   end subroutine emit_const

   !> Append an operation or a variable, folding it into a constant when its operands are.
   !> `at` is the column blamed if folding meets a domain error (default: the current one).
   subroutine emit(p, op, at)
      type(parser_t), intent(inout) :: p
      integer, intent(in) :: op
      integer, intent(in), optional :: at

      integer :: status, arity
      real(dp) :: a, b, c

      if (op == op_x .or. op == op_y .or. op == op_r) then
         call push(p, op, 0.0_dp)
         p%depth = p%depth + 1
         call track_depth(p)
         return
      end if
      arity = merge(2, 1, is_binary(op))
      if (p%n >= arity) then
         if (all(p%op(p%n - arity + 1:p%n) == op_const)) then
            a = p%value(p%n - arity + 1)
            b = 0.0_dp
            if (arity == 2) b = p%value(p%n)
            select case (op)
            case (op_neg); c = -a; status = status_ok
            case (op_abs); c = abs(a); status = status_ok
            case (op_sin); c = sin(a); status = status_ok
            case (op_cos); c = cos(a); status = status_ok
            case (op_min); c = min(a, b); status = status_ok
            case (op_max); c = max(a, b); status = status_ok
            case (op_lt, op_le, op_gt, op_ge, op_eq, op_ne); c = compare(op, a, b); status = status_ok
            case default; call apply(op, a, b, c, status)
            end select
            if (status /= status_ok) then
               if (present(at)) then
                  call fail_at(p, at, formula_status_text(status))
               else
                  call fail(p, formula_status_text(status))
               end if
               return
            end if
            p%n = p%n - arity
            p%depth = p%depth - arity
            call emit_const(p, c)
            return
         end if
      end if
      if (op == op_pow .and. p%op(p%n) == op_const) then
         ! x^2, the commonest power, as one multiplication (same value as a**2)
         if (p%value(p%n) == 2) then
            p%n = p%n - 1
            p%depth = p%depth - 1
            call push(p, op_square, 0.0_dp)
            return
         end if
      end if
      call push(p, op, 0.0_dp)
      p%depth = p%depth - (arity - 1)
   end subroutine emit

   subroutine push(p, op, v)
      type(parser_t), intent(inout) :: p
      integer, intent(in) :: op
      real(dp), intent(in) :: v

      integer, allocatable :: op_new(:)
      real(dp), allocatable :: value_new(:)

      if (p%n == size(p%op)) then
         allocate (op_new(2*p%n), value_new(2*p%n))
         op_new(1:p%n) = p%op
         value_new(1:p%n) = p%value
         call move_alloc(op_new, p%op)
         call move_alloc(value_new, p%value)
      end if
      p%n = p%n + 1
      p%op(p%n) = op
      p%value(p%n) = v
   end subroutine push

   subroutine track_depth(p)
      type(parser_t), intent(inout) :: p

      p%max_seen = max(p%max_seen, p%depth)
      if (p%max_seen > max_depth .and. .not. allocated(p%err)) &
         call fail(p, 'the formula nests too deeply (more than 48 pending values)')
   end subroutine track_depth

   subroutine skip_blanks(p)
      type(parser_t), intent(inout) :: p

      do while (p%pos <= len(p%s))
         if (p%s(p%pos:p%pos) /= ' ' .and. p%s(p%pos:p%pos) /= achar(9)) exit
         p%pos = p%pos + 1
      end do
   end subroutine skip_blanks

   subroutine fail(p, why)
      type(parser_t), intent(inout) :: p
      character(len=*), intent(in) :: why

      call fail_at(p, min(p%pos, len(p%s) + 1), why)
   end subroutine fail

   subroutine fail_at(p, at, why)
      type(parser_t), intent(inout) :: p
      integer, intent(in) :: at
      character(len=*), intent(in) :: why

      if (allocated(p%err)) return
      p%err_pos = at
      p%err = why
   end subroutine fail_at

   pure logical function is_digit(c)
      character, intent(in) :: c

      is_digit = c >= '0' .and. c <= '9'
   end function is_digit

   pure logical function is_letter(c)
      character, intent(in) :: c

      is_letter = (c >= 'a' .and. c <= 'z') .or. (c >= 'A' .and. c <= 'Z')
   end function is_letter

   pure function lower(s) result(t)
      character(len=*), intent(in) :: s
      character(len=len(s)) :: t

      integer :: i

      t = s
      do i = 1, len(s)
         if (s(i:i) >= 'A' .and. s(i:i) <= 'Z') t(i:i) = achar(iachar(s(i:i)) + 32)
      end do
   end function lower
end module twomem_input_formula
