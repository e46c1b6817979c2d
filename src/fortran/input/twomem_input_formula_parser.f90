!> The parser of load formulas: recursive descent over the grammar below into the postfix
!> instruction list of a `formula_t` (twomem_input_formula), folding every subexpression whose
!> operands are constants with the evaluator's own operations, so folding and evaluation
!> cannot disagree. An error gives the 1-based column and the reason, for the one-line input
!> error that names the key.
module twomem_input_formula_parser
   use twomem_base_kinds, only: dp
   use twomem_base_text, only: to_lower
   use twomem_base_errors, only: excerpt
   use twomem_input_values, only: scan_real
   use twomem_input_formula, only: formula_t, formula_status_text, status_ok, max_depth, apply, compare, &
      is_binary, op_const, op_x, op_y, op_r, op_add, op_sub, op_mul, op_div, op_pow, op_neg, op_lt, op_le, &
      op_gt, op_ge, op_eq, op_ne, op_sqrt, op_exp, op_log, op_sin, op_cos, op_tan, op_atan2, op_abs, op_min, &
      op_max, op_square
   implicit none
   private

   public :: parse_formula

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
      name = to_lower(p%s(start:p%pos - 1))
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
         call fail_at(p, start, "unknown name '"//excerpt(name)//"' (variables: x, y, r, pi; functions: sqrt, exp, log, "// &
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
end module twomem_input_formula_parser
