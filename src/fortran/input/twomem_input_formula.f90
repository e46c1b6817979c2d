!> Formulas of position for user data such as `problem.f1 = '-0.4 - 0.1*(r <= sqrt(0.5))'`:
!> a postfix instruction list (made by twomem_input_formula_parser) that a small stack machine
!> evaluates at many points. Evaluation must be cheap (it runs at every quadrature
!> point of every assembly) and must never raise a floating-point exception (debug builds trap
!> them): every operation checks its domain first, so every value on the stack stays finite,
!> and a violation stops the evaluation with a status whose reason `formula_status_text` names.
!> The instruction codes and `apply`, `compare`, `is_binary` are public for the parser, which
!> folds constant subexpressions with them, so that `sqrt(0.5)` costs nothing per point.
module twomem_input_formula
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: formula_t, formula_status_text, status_ok
   ! for the parser
   public :: max_depth, apply, compare, is_binary
   public :: op_const, op_x, op_y, op_r, op_add, op_sub, op_mul, op_div, op_pow, op_neg, op_lt, op_le, op_gt, &
      op_ge, op_eq, op_ne, op_sqrt, op_exp, op_log, op_sin, op_cos, op_tan, op_atan2, op_abs, op_min, op_max, &
      op_square

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

contains

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
end module twomem_input_formula
