!> Mutations of a valid input text, the raw material of the fuzzer. Byte-level edits (flips,
!> deletions, random insertions, truncation, long runs) find what a careless scanner trips on;
!> token and line edits (a number replaced by -1 or 1e999, a `$EndNodes` dropped in, a line
!> repeated or swapped, a section duplicated, CRLF line ends) keep most of the structure, so the
!> mutated file gets past the header and reaches the deeper checks. What to drop in comes from
!> a dictionary that the caller fills for its format.
module fuzz_mutate
   use twomem_base_kinds, only: dp
   use fuzz_random, only: rng_t
   implicit none
   private

   public :: word_t, mutate, mutate_once, add_word

   !> One dictionary entry (a token or a whole line).
   type :: word_t
      character(len=:), allocatable :: s
   end type word_t

   !> Inputs never grow beyond this, so a run of growing mutations stays cheap.
   integer, parameter :: max_length = 400000
   integer, parameter :: n_kinds = 16
   character, parameter :: lf = achar(10), cr = achar(13)

contains

   !> Append `s` to the dictionary.
   subroutine add_word(words, s)
      type(word_t), allocatable, intent(inout) :: words(:)
      character(len=*), intent(in) :: s

      type(word_t) :: w

      if (.not. allocated(words)) allocate (words(0))
      w%s = s
      words = [words, w]
   end subroutine add_word

   !> One to four stacked mutations: single edits are the most productive, stacks reach states
   !> no single edit can.
   subroutine mutate(text, rng, words)
      character(len=:), allocatable, intent(inout) :: text
      type(rng_t), intent(inout) :: rng
      type(word_t), intent(in) :: words(:)

      integer :: i, n

      n = 1
      if (rng%chance(0.4_dp)) n = rng%between(2, 4)
      do i = 1, n
         call mutate_once(text, rng, words)
      end do
      if (len(text) > max_length) text = text(1:max_length)
   end subroutine mutate

   subroutine mutate_once(text, rng, words)
      character(len=:), allocatable, intent(inout) :: text
      type(rng_t), intent(inout) :: rng
      type(word_t), intent(in) :: words(:)

      integer :: p, q, k, n
      ! Random numbers are drawn into variables before they are used: gfortran may evaluate a
      ! function reference in a substring or a length twice, and each call draws anew.
      character(len=:), allocatable :: w

      n = len(text)
      select case (rng%below(n_kinds))
      case (0) ! one byte replaced by any byte, NUL and high bytes included
         if (n == 0) return
         p = rng%between(1, n)
         text(p:p) = char(rng%below(256))
      case (1) ! one bit flipped
         if (n == 0) return
         p = rng%between(1, n)
         text(p:p) = char(ieor(ichar(text(p:p)), 2**rng%below(8)))
      case (2) ! a short span deleted
         if (n == 0) return
         p = rng%between(1, n)
         q = min(n, p + rng%below(16))
         text = text(1:p - 1)//text(q + 1:)
      case (3) ! a long span deleted
         if (n == 0) return
         p = rng%between(1, n)
         q = min(n, p + rng%below(max(1, n/4)))
         text = text(1:p - 1)//text(q + 1:)
      case (4) ! a few random bytes inserted
         p = rng%between(1, n + 1)
         k = rng%between(1, 8)
         w = random_bytes(rng, k)
         text = text(1:p - 1)//w//text(p:)
      case (5) ! truncation at a random point
         if (n == 0) return
         p = rng%below(n)
         text = text(1:p)
      case (6) ! a dictionary word inserted anywhere
         p = rng%between(1, n + 1)
         w = pick(rng, words)
         text = text(1:p - 1)//w//text(p:)
      case (7, 8) ! a whitespace-delimited token replaced by a dictionary word
         w = pick(rng, words)
         call replace_token(text, rng, w)
      case (9) ! a dictionary word on a line of its own
         p = line_start(text, rng)
         w = pick(rng, words)
         text = text(1:p - 1)//w//lf//text(p:)
      case (10) ! a line deleted
         call line_span(text, rng, p, q)
         text = text(1:p - 1)//text(q + 1:)
      case (11) ! a line repeated
         call line_span(text, rng, p, q)
         text = text(1:q)//text(p:q)//text(q + 1:)
      case (12) ! two lines swapped
         call swap_lines(text, rng)
      case (13) ! a block of lines (a section, often) repeated after itself
         p = line_start(text, rng)
         q = line_start(text, rng)
         if (q < p) then
            k = p
            p = q
            q = k
         end if
         text = text(1:q - 1)//text(p:q - 1)//text(q:)
      case (14) ! line ends: CRLF everywhere, or one lone CR
         if (rng%chance(0.5_dp)) then
            text = crlf(text)
         else
            p = rng%between(1, n + 1)
            text = text(1:p - 1)//cr//text(p:)
         end if
      case (15) ! a long run of one character: long lines, long tokens, long strings
         p = rng%between(1, n + 1)
         k = rng%between(300, 70000)
         w = run_char(rng)
         text = text(1:p - 1)//repeat(w, k)//text(p:)
      end select
   end subroutine mutate_once

   function random_bytes(rng, n) result(s)
      type(rng_t), intent(inout) :: rng
      integer, intent(in) :: n
      character(len=n) :: s

      integer :: i

      do i = 1, n
         s(i:i) = char(rng%below(256))
      end do
   end function random_bytes

   function pick(rng, words) result(s)
      type(rng_t), intent(inout) :: rng
      type(word_t), intent(in) :: words(:)
      character(len=:), allocatable :: s

      integer :: i

      if (size(words) == 0) then
         s = ''
      else
         ! the index first: gfortran may evaluate a subscript twice (for the length and for
         ! the text), and each evaluation here draws a new number
         i = rng%between(1, size(words))
         s = words(i)%s
      end if
   end function pick

   function run_char(rng) result(c)
      type(rng_t), intent(inout) :: rng
      character :: c

      character(len=*), parameter :: choices = '9x 0.'//"'"//'"&/='//achar(0)//achar(9)
      integer :: i

      i = rng%between(1, len(choices))
      c = choices(i:i)
   end function run_char

   !> Token boundaries are blanks and control characters, as in both readers.
   pure logical function is_blank(c)
      character, intent(in) :: c

      is_blank = iachar(c) <= 32
   end function is_blank

   !> Replace the token that covers a random position (or the next one) by `word`.
   subroutine replace_token(text, rng, word)
      character(len=:), allocatable, intent(inout) :: text
      type(rng_t), intent(inout) :: rng
      character(len=*), intent(in) :: word

      integer :: n, p, q

      n = len(text)
      if (n == 0) return
      p = rng%between(1, n)
      do while (p <= n)
         if (.not. is_blank(text(p:p))) exit
         p = p + 1
      end do
      if (p > n) return
      do while (p > 1)
         if (is_blank(text(p - 1:p - 1))) exit
         p = p - 1
      end do
      q = p
      do while (q < n)
         if (is_blank(text(q + 1:q + 1))) exit
         q = q + 1
      end do
      text = text(1:p - 1)//word//text(q + 1:)
   end subroutine replace_token

   !> Start of a random line (or len+1, the end of the text).
   integer function line_start(text, rng) result(p)
      character(len=*), intent(in) :: text
      type(rng_t), intent(inout) :: rng

      p = rng%between(1, len(text) + 1)
      do while (p > 1)
         if (text(p - 1:p - 1) == lf) exit
         p = p - 1
      end do
   end function line_start

   !> Bounds p..q of a random line, its newline included (q = p - 1 for an empty text).
   subroutine line_span(text, rng, p, q)
      character(len=*), intent(in) :: text
      type(rng_t), intent(inout) :: rng
      integer, intent(out) :: p, q

      p = line_start(text, rng)
      q = p - 1
      if (p > len(text)) return
      q = index(text(p:), lf)
      if (q == 0) then
         q = len(text)
      else
         q = p + q - 1
      end if
   end subroutine line_span

   subroutine swap_lines(text, rng)
      character(len=:), allocatable, intent(inout) :: text
      type(rng_t), intent(inout) :: rng

      integer :: p1, q1, p2, q2, k

      call line_span(text, rng, p1, q1)
      call line_span(text, rng, p2, q2)
      if (p2 < p1) then
         k = p1; p1 = p2; p2 = k
         k = q1; q1 = q2; q2 = k
      end if
      ! overlapping spans are the same line: nothing to swap
      if (q1 >= p2 .or. q1 < p1 .or. q2 < p2) return
      text = text(1:p1 - 1)//text(p2:q2)//text(q1 + 1:p2 - 1)//text(p1:q1)//text(q2 + 1:)
   end subroutine swap_lines

   !> Every LF preceded by a CR (an existing CR stays, so CRCRLF can occur too).
   function crlf(text) result(out)
      character(len=*), intent(in) :: text
      character(len=:), allocatable :: out

      integer :: i, m

      allocate (character(len=2*len(text)) :: out)
      m = 0
      do i = 1, len(text)
         if (text(i:i) == lf) then
            m = m + 1
            out(m:m) = cr
         end if
         m = m + 1
         out(m:m) = text(i:i)
      end do
      out = out(1:m)
   end function crlf
end module fuzz_mutate
