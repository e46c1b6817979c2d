!> The value syntax of namelists, one value at a time: scanning integers, reals, logicals and
!> quoted strings with a message a user can act on, and printing values back so that they scan
!> to the same bits. Shared by the case-file parser and the command-line overrides, so both
!> accept exactly the same spellings.
module twomem_input_values
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite, ieee_is_nan
   use, intrinsic :: ieee_exceptions, only: ieee_status_type, ieee_get_status, ieee_set_status, &
      ieee_get_halting_mode, ieee_set_halting_mode, ieee_usual
   use twomem_base_kinds, only: dp, i8
   use twomem_base_errors, only: excerpt
   use twomem_base_text, only: int_text, to_lower
   implicit none
   private

   public :: scan_integer, scan_real, scan_logical, unquote, scan_quoted
   public :: format_real, quote

contains

   !> Integer in namelist syntax: optional sign and digits only (so `1.0`, `1e3` are rejected
   !> rather than truncated). `what` stays unallocated on success.
   subroutine scan_integer(text, value, what)
      character(len=*), intent(in) :: text
      integer, intent(out) :: value
      character(len=:), allocatable, intent(out) :: what

      integer :: p, ios
      integer(i8) :: wide

      value = 0
      p = 1
      if (len(text) > 0) then
         if (text(1:1) == '+' .or. text(1:1) == '-') p = 2
      end if
      if (p > len(text) .or. verify(text(p:), '0123456789') /= 0) then
         what = 'expected an integer, got '//quote(excerpt(text))
         return
      end if
      if (len(text) - p + 1 > 18) then
         what = 'integer out of range, got '//excerpt(text)
         return
      end if
      read (text, *, iostat=ios) wide
      if (ios /= 0 .or. abs(wide) > huge(value)) then
         what = 'integer out of range, got '//excerpt(text)
         return
      end if
      value = int(wide)
   end subroutine scan_integer

   !> Real in namelist syntax (`1`, `-2.5`, `.5`, `1e-10`, `1.d-3`); `nan` and `inf` are read so
   !> that validation can name them. An overflowing literal is an error here.
   subroutine scan_real(text, value, what)
      character(len=*), intent(in) :: text
      real(dp), intent(out) :: value
      character(len=:), allocatable, intent(out) :: what

      character(len=:), allocatable :: t
      logical :: special
      integer :: ios, p

      value = 0.0_dp
      t = to_lower(text)
      p = 1
      if (len(t) > 0) then
         if (t(1:1) == '+' .or. t(1:1) == '-') p = 2
      end if
      special = .false.
      if (p <= len(t)) special = t(p:) == 'nan' .or. t(p:) == 'inf' .or. t(p:) == 'infinity'
      if (.not. (special .or. is_real_literal(t(p:)))) then
         what = 'expected a real number, got '//quote(excerpt(text))
         return
      end if
      call read_quietly(t, value, ios)
      if (ios /= 0) then
         value = 0.0_dp
         what = 'expected a real number, got '//quote(excerpt(text))
      else if (.not. special .and. .not. ieee_is_finite(value)) then
         value = 0.0_dp
         what = 'real number out of range, got '//excerpt(text)
      end if
   end subroutine scan_real

   !> A list-directed read with floating-point trapping switched off: debug builds trap on
   !> overflow, and the run-time library's strtod overflows on `1e999` before we can object.
   subroutine read_quietly(text, value, ios)
      character(len=*), intent(in) :: text
      real(dp), intent(out) :: value
      integer, intent(out) :: ios

      type(ieee_status_type) :: status
      logical :: halting(size(ieee_usual))

      call ieee_get_status(status)
      call ieee_get_halting_mode(ieee_usual, halting)
      call ieee_set_halting_mode(ieee_usual, .false.)
      read (text, *, iostat=ios) value
      call ieee_set_status(status)
      call ieee_set_halting_mode(ieee_usual, halting)
   end subroutine read_quietly

   !> digits [. [digits]] | . digits, then an optional exponent (e|d)[sign]digits
   pure logical function is_real_literal(t) result(ok)
      character(len=*), intent(in) :: t

      integer :: p, n_int, n_frac, n_exp

      ok = .false.
      p = 1
      call span_digits(t, p, n_int)
      n_frac = 0
      if (p <= len(t)) then
         if (t(p:p) == '.') then
            p = p + 1
            call span_digits(t, p, n_frac)
         end if
      end if
      if (n_int + n_frac == 0) return
      if (p <= len(t)) then
         if (t(p:p) /= 'e' .and. t(p:p) /= 'd') return
         p = p + 1
         if (p <= len(t)) then
            if (t(p:p) == '+' .or. t(p:p) == '-') p = p + 1
         end if
         call span_digits(t, p, n_exp)
         if (n_exp == 0) return
      end if
      ok = p > len(t)
   end function is_real_literal

   !> Number of digits from position `p`, which is moved past them.
   pure subroutine span_digits(t, p, n)
      character(len=*), intent(in) :: t
      integer, intent(inout) :: p
      integer, intent(out) :: n

      n = 0
      do while (p <= len(t))
         if (index('0123456789', t(p:p)) == 0) exit
         p = p + 1
         n = n + 1
      end do
   end subroutine span_digits

   !> The logical spellings a namelist user writes: `.true.`, `.t.`, `t`, `true` and the false
   !> ones. Stricter than Fortran's reader, which takes any word starting with t or f.
   subroutine scan_logical(text, value, what)
      character(len=*), intent(in) :: text
      logical, intent(out) :: value
      character(len=:), allocatable, intent(out) :: what

      value = .false.
      select case (to_lower(text))
      case ('.true.', '.t.', 't', 'true')
         value = .true.
      case ('.false.', '.f.', 'f', 'false')
         value = .false.
      case default
         what = 'expected a logical (.true. or .false.), got '//quote(excerpt(text))
      end select
   end subroutine scan_logical

   !> The text of a value written as '...' or "..." (doubled delimiter inside), or `text` itself
   !> when it does not start with a quote. `what` is set when a quoted value is malformed.
   subroutine unquote(text, value, quoted, what)
      character(len=*), intent(in) :: text
      character(len=:), allocatable, intent(out) :: value
      logical, intent(out) :: quoted
      character(len=:), allocatable, intent(out) :: what

      integer :: close

      quoted = .false.
      value = text
      if (len(text) == 0) return
      if (text(1:1) /= "'" .and. text(1:1) /= '"') return
      quoted = .true.
      call scan_quoted(text, 1, value, close)
      if (close == 0) then
         what = 'unterminated string'
      else if (close /= len(text)) then
         what = 'unexpected text after the closing quote'
      end if
   end subroutine unquote

   !> The string literal that opens with the quote at text(start:start): its text, with each
   !> doubled delimiter inside read as one, and the position of its closing quote (`close`; 0
   !> when `text` ends first, and `value` is then the text up to there). The one reading of
   !> quoted text, for the case-file tokenizer and the overrides alike.
   pure subroutine scan_quoted(text, start, value, close)
      character(len=*), intent(in) :: text
      integer, intent(in) :: start
      character(len=:), allocatable, intent(out) :: value
      integer, intent(out) :: close

      character :: delim
      !> one past the literal's text: its closing quote, or the end of `text`
      integer :: last
      integer :: q, k

      delim = text(start:start)
      ! first the closing quote, so that the text is allocated once and filled in place: growing
      ! a string a character at a time costs quadratic time, minutes on a long line
      close = 0
      q = start + 1
      do while (q <= len(text))
         if (text(q:q) == delim) then
            if (q == len(text)) then
               close = q
               exit
            else if (text(q + 1:q + 1) /= delim) then
               close = q
               exit
            end if
            q = q + 1
         end if
         q = q + 1
      end do
      last = merge(close, len(text) + 1, close > 0)
      allocate (character(len=last - start - 1) :: value)
      k = 0
      q = start + 1
      do while (q < last)
         k = k + 1
         value(k:k) = text(q:q)
         ! a doubled delimiter stands for one
         if (text(q:q) == delim) q = q + 1
         q = q + 1
      end do
      value = value(1:k)
   end subroutine scan_quoted

   !> Shortest decimal text that reads back to exactly `x` (at most 17 significant digits),
   !> positional for moderate magnitudes and with an exponent otherwise: '0.25', '1.0e-10'.
   function format_real(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s

      character(len=40) :: buf, fmt
      character(len=:), allocatable :: digits, what
      real(dp) :: y
      integer :: d, k, e, ios

      if (ieee_is_nan(x)) then
         s = 'NaN'
         return
      else if (.not. ieee_is_finite(x)) then
         s = 'Infinity'
         if (x < 0.0_dp) s = '-Infinity'
         return
      end if
      do d = 0, 16
         write (fmt, '(a,i0,a)') '(es40.', d, 'e3)'
         write (buf, fmt) x
         call read_quietly(buf, y, ios)
         if (ios == 0 .and. same_bits(x, y)) exit
      end do
      buf = adjustl(buf)
      k = index(buf, 'E')
      read (buf(k + 1:), *) e
      digits = ''
      do d = 1, k - 1
         if (index('0123456789', buf(d:d)) > 0) digits = digits//buf(d:d)
      end do
      s = ''
      if (buf(1:1) == '-') s = '-'
      if (e >= -4 .and. e < 7) then
         if (e >= 0) then
            if (len(digits) <= e + 1) then
               s = s//digits//repeat('0', e + 1 - len(digits))//'.0'
            else
               s = s//digits(1:e + 1)//'.'//digits(e + 2:)
            end if
         else
            s = s//'0.'//repeat('0', -e - 1)//digits
         end if
      else
         if (len(digits) == 1) digits = digits//'0'
         s = s//digits(1:1)//'.'//digits(2:)//'e'//int_text(e)
      end if
      call scan_real(s, y, what)
      if (allocated(what) .or. .not. same_bits(x, y)) then
         write (buf, '(es24.16e3)') x
         s = trim(adjustl(buf))
      end if
   end function format_real

   logical function same_bits(a, b)
      real(dp), intent(in) :: a, b

      same_bits = transfer(a, 0_i8) == transfer(b, 0_i8)
   end function same_bits

   !> `s` in single quotes with inner quotes doubled: a namelist string literal.
   pure function quote(s) result(q)
      character(len=*), intent(in) :: s
      character(len=:), allocatable :: q

      integer :: i

      q = "'"
      do i = 1, len(s)
         if (s(i:i) == "'") then
            q = q//"''"
         else
            q = q//s(i:i)
         end if
      end do
      q = q//"'"
   end function quote
end module twomem_input_values
