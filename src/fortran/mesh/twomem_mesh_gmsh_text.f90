!> Line-oriented reading of a text mesh file for the Gmsh reader. A `text_reader_t` hands out one
!> line at a time, split into whitespace-separated tokens, and turns every malformed token into an
!> error that names the file and the line. Numbers are checked against a strict grammar before any
!> internal read sees them, because a list-directed read accepts commas, slashes and repeat counts
!> as valid input, and converting an overflowing literal such as 1e999 traps under
!> -ffpe-trap=overflow instead of failing through `iostat`; a checked number is then converted by
!> the C library (twomem_base_system%decimal_value), the internal read remaining for tokens too
!> long for it. The file is read as a stream, a block of bytes at a time, and cut into lines
!> here rather than by a formatted read per line.
module twomem_mesh_gmsh_text
   use twomem_base_kinds, only: dp, i8
   use twomem_base_errors, only: error_t, make_error, exit_bad_input, excerpt
   use twomem_base_text, only: int_text, to_lower
   use twomem_base_system, only: decimal_value
   implicit none
   private

   public :: text_reader_t

   !> initial length of the line buffer
   integer, parameter :: chunk_len = 1024
   !> bytes read from the file at a time
   integer, parameter :: block_len = 2**20
   !> Largest decimal exponent accepted: keeps every conversion clear of overflow.
   integer, parameter :: max_exponent10 = range(1.0_dp) - 1

   type :: text_reader_t
      character(len=:), allocatable :: path
      integer :: unit = -1
      logical :: is_open = .false.
      !> the file's bytes block(cursor:filled) are read but not yet cut into lines; the file's
      !> byte `offset` is the first not yet read, of `file_size`
      character(len=:), allocatable :: block
      integer :: cursor = 1, filled = 0
      integer(i8) :: offset = 1, file_size = 0
      !> number of the current line (1-based), 0 before the first line
      integer :: line_no = 0
      !> the current line is buf(1:n); buf only grows, so long lines cost one allocation
      character(len=:), allocatable :: buf
      integer :: n = 0
      integer :: n_tokens = 0
      integer, allocatable :: first(:), last(:)
   contains
      procedure :: open => reader_open
      procedure :: close => reader_close
      procedure :: next => reader_next
      procedure :: next_data
      procedure :: expect_end
      procedure :: token
      procedure :: shown
      procedure :: at
      procedure :: fail
      procedure :: expect_tokens
      procedure :: get_int
      procedure :: get_real
   end type text_reader_t

contains

   !> Open `path` for reading; a missing or unreadable file is bad input like any other.
   subroutine reader_open(self, path, err)
      class(text_reader_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out) :: err

      integer :: ios
      character(len=256) :: msg

      call self%close()
      self%path = path
      self%line_no = 0
      self%n = 0
      self%n_tokens = 0
      if (.not. allocated(self%buf)) allocate (character(len=chunk_len) :: self%buf)
      if (.not. allocated(self%first)) allocate (self%first(16), self%last(16))
      if (.not. allocated(self%block)) allocate (character(len=block_len) :: self%block)
      self%cursor = 1
      self%filled = 0
      self%offset = 1
      msg = ''
      open (newunit=self%unit, file=path, status='old', action='read', form='unformatted', &
            access='stream', iostat=ios, iomsg=msg)
      if (ios /= 0) then
         call make_error(err, exit_bad_input, path, 'cannot open the mesh file: '//trim(msg))
         return
      end if
      self%is_open = .true.
      inquire (unit=self%unit, size=self%file_size, iostat=ios, iomsg=msg)
      if (ios == 0 .and. self%file_size < 0) then
         ios = 1
         msg = 'its size is unknown (not a regular file)'
      end if
      if (ios /= 0) then
         call make_error(err, exit_bad_input, path, 'cannot open the mesh file: '//trim(msg))
         call self%close()
      end if
   end subroutine reader_open

   subroutine reader_close(self)
      class(text_reader_t), intent(inout) :: self

      integer :: ios

      if (self%is_open) close (self%unit, iostat=ios)
      self%is_open = .false.
      self%unit = -1
   end subroutine reader_close

   !> Read the next line, whatever its length, and split it into tokens. `eof` is set at the end of
   !> the file; a last line without a newline still counts as a line.
   subroutine reader_next(self, eof, err)
      class(text_reader_t), intent(inout) :: self
      logical, intent(out) :: eof
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: wider
      integer :: ios, got, newline
      character(len=256) :: msg

      eof = .false.
      self%n = 0
      self%n_tokens = 0
      do
         if (self%cursor > self%filled) then
            ! the block is used up: the next one, or the end of the file
            if (self%offset > self%file_size) then
               if (self%n > 0) exit
               eof = .true.
               return
            end if
            got = int(min(int(len(self%block), i8), self%file_size - self%offset + 1))
            msg = ''
            read (self%unit, pos=self%offset, iostat=ios, iomsg=msg) self%block(1:got)
            if (ios /= 0) then
               call make_error(err, exit_bad_input, self%path//':'//int_text(self%line_no + 1), &
                               'cannot read the line: '//trim(msg))
               return
            end if
            self%offset = self%offset + got
            self%cursor = 1
            self%filled = got
         end if
         newline = index(self%block(self%cursor:self%filled), achar(10))
         got = merge(newline - 1, self%filled - self%cursor + 1, newline > 0)
         if (self%n + got > len(self%buf)) then
            allocate (character(len=2*(self%n + got)) :: wider)
            wider(1:self%n) = self%buf(1:self%n)
            call move_alloc(wider, self%buf)
         end if
         self%buf(self%n + 1:self%n + got) = self%block(self%cursor:self%cursor + got - 1)
         self%n = self%n + got
         self%cursor = self%cursor + got
         if (newline > 0) then
            self%cursor = self%cursor + 1
            exit
         end if
      end do
      self%line_no = self%line_no + 1
      call split(self)
   end subroutine reader_next

   !> Any control character separates tokens, so tabs and the CR of Windows line ends are blanks.
   subroutine split(self)
      type(text_reader_t), intent(inout) :: self

      integer :: i
      logical :: in_token
      integer, allocatable :: wider(:)

      self%n_tokens = 0
      in_token = .false.
      do i = 1, self%n
         if (iachar(self%buf(i:i)) <= 32) then
            in_token = .false.
            cycle
         end if
         if (.not. in_token) then
            if (self%n_tokens == size(self%first)) then
               allocate (wider(2*size(self%first)))
               wider(1:self%n_tokens) = self%first
               call move_alloc(wider, self%first)
               allocate (wider(2*size(self%last)))
               wider(1:self%n_tokens) = self%last
               call move_alloc(wider, self%last)
            end if
            self%n_tokens = self%n_tokens + 1
            self%first(self%n_tokens) = i
            in_token = .true.
         end if
         self%last(self%n_tokens) = i
      end do
   end subroutine split

   !> The next non-blank line inside `section`, which must not end before `what` (item `item` of
   !> `total`, if given) is read: the end of the file or a `$` line here means the section is
   !> truncated or its count is too large. With `n_tokens`, the line must hold exactly that many
   !> entries, described by `layout`. Messages are composed only on error: this runs per line.
   subroutine next_data(self, section, what, err, n_tokens, layout, item, total)
      class(text_reader_t), intent(inout) :: self
      character(len=*), intent(in) :: section, what
      type(error_t), allocatable, intent(out) :: err
      integer, intent(in), optional :: n_tokens
      character(len=*), intent(in), optional :: layout
      integer(i8), intent(in), optional :: item, total

      logical :: eof

      do
         call self%next(eof, err)
         if (allocated(err)) return
         if (eof) then
            call make_error(err, exit_bad_input, self%path//':'//int_text(self%line_no), &
                            'the file ends inside the '//section//' section, before '// &
                            numbered(what, item, total))
            return
         end if
         if (self%n_tokens > 0) exit
      end do
      if (self%buf(self%first(1):self%first(1)) == '$') then
         call self%fail(err, 'the '//section//' section is truncated: found '//self%shown(1)// &
                        ' where '//numbered(what, item, total)//' should be')
      else if (present(n_tokens) .and. present(layout)) then
         call self%expect_tokens(n_tokens, layout, err)
      end if
   end subroutine next_data

   pure function numbered(what, item, total) result(text)
      character(len=*), intent(in) :: what
      integer(i8), intent(in), optional :: item, total
      character(len=:), allocatable :: text

      text = what
      if (present(item) .and. present(total)) text = what//' '//int_text(item)//' of '//int_text(total)
   end function numbered

   !> The line after the last entry must close the section; anything else means the section holds
   !> more entries than its count announced.
   subroutine expect_end(self, section, err)
      class(text_reader_t), intent(inout) :: self
      character(len=*), intent(in) :: section
      type(error_t), allocatable, intent(out) :: err

      logical :: eof
      character(len=:), allocatable :: closing

      closing = '$End'//section(2:)
      do
         call self%next(eof, err)
         if (allocated(err)) return
         if (eof) then
            call make_error(err, exit_bad_input, self%path//':'//int_text(self%line_no), &
                            'the file ends before '//closing)
            return
         end if
         if (self%n_tokens > 0) exit
      end do
      if (self%token(1) /= closing) then
         call self%fail(err, 'expected '//closing//', found "'//self%shown(1)//'": the '// &
                        section//' section holds more entries than its header says')
      end if
   end subroutine expect_end

   function token(self, i) result(t)
      class(text_reader_t), intent(in) :: self
      integer, intent(in) :: i
      character(len=:), allocatable :: t

      t = self%buf(self%first(i):self%last(i))
   end function token

   !> Token `i` as a message quotes it: cut short and with control characters spelled out.
   function shown(self, i) result(t)
      class(text_reader_t), intent(in) :: self
      integer, intent(in) :: i
      character(len=:), allocatable :: t

      t = excerpt(self%buf(self%first(i):self%last(i)))
   end function shown

   !> `file:line` of the current line, the prefix of every message about its content.
   function at(self) result(where)
      class(text_reader_t), intent(in) :: self
      character(len=:), allocatable :: where

      where = self%path//':'//int_text(self%line_no)
   end function at

   subroutine fail(self, err, what)
      class(text_reader_t), intent(in) :: self
      type(error_t), allocatable, intent(out) :: err
      character(len=*), intent(in) :: what

      call make_error(err, exit_bad_input, self%at(), what)
   end subroutine fail

   subroutine expect_tokens(self, n, what, err)
      class(text_reader_t), intent(in) :: self
      integer, intent(in) :: n
      character(len=*), intent(in) :: what
      type(error_t), allocatable, intent(out) :: err

      if (self%n_tokens /= n) then
         call self%fail(err, 'expected '//int_text(n)//trim(merge(' entry  ', ' entries', n == 1))// &
                        ' ('//what//'), found '//int_text(self%n_tokens))
      end if
   end subroutine expect_tokens

   !> Token `i` as an integer in [lo, hi]; `what` names the entry in the message.
   subroutine get_int(self, i, lo, hi, what, value, err)
      class(text_reader_t), intent(in) :: self
      integer, intent(in) :: i
      integer(i8), intent(in) :: lo, hi
      character(len=*), intent(in) :: what
      integer(i8), intent(out) :: value
      type(error_t), allocatable, intent(out) :: err

      logical :: ok

      value = 0
      if (i > self%n_tokens) then
         call self%fail(err, 'the line ends before '//what)
         return
      end if
      call parse_int(self%buf(self%first(i):self%last(i)), value, ok)
      if (.not. ok) then
         call self%fail(err, '"'//self%shown(i)//'" is not an integer ('//what//')')
      else if (value < lo .or. value > hi) then
         call self%fail(err, what//' '//self%shown(i)//' is out of range ['//int_text(lo)//', '// &
                        int_text(hi)//']')
      end if
   end subroutine get_int

   !> Token `i` as a finite real.
   subroutine get_real(self, i, what, value, err)
      class(text_reader_t), intent(in) :: self
      integer, intent(in) :: i
      character(len=*), intent(in) :: what
      real(dp), intent(out) :: value
      type(error_t), allocatable, intent(out) :: err

      integer :: status

      value = 0.0_dp
      if (i > self%n_tokens) then
         call self%fail(err, 'the line ends before '//what)
         return
      end if
      call parse_real(self%buf(self%first(i):self%last(i)), value, status)
      select case (status)
      case (1)
         call self%fail(err, '"'//self%shown(i)//'" is not a number ('//what//')')
      case (2)
         call self%fail(err, what//' "'//self%shown(i)//'" is not finite (NaN, infinite or '// &
                        'out of range)')
      end select
   end subroutine get_real

   !> [sign] digits, at most 18 of them so that the value fits in 64 bits.
   pure subroutine parse_int(text, value, ok)
      character(len=*), intent(in) :: text
      integer(i8), intent(out) :: value
      logical, intent(out) :: ok

      integer :: i, start
      logical :: negative

      value = 0
      ok = .false.
      negative = text(1:1) == '-'
      start = 1
      if (text(1:1) == '-' .or. text(1:1) == '+') start = 2
      if (len(text) < start .or. len(text) - start + 1 > 18) return
      do i = start, len(text)
         if (.not. is_digit(text(i:i))) return
         value = 10*value + (iachar(text(i:i)) - iachar('0'))
      end do
      if (negative) value = -value
      ok = .true.
   end subroutine parse_int

   !> status 0: a finite number; 1: not a number; 2: NaN, infinity or beyond the range of dp.
   !> Accepts [sign] digits [. [digits]] or [sign] . digits, then optionally
   !> (e|E|d|D) [sign] digits.
   subroutine parse_real(text, value, status)
      character(len=*), intent(in) :: text
      real(dp), intent(out) :: value
      integer, intent(out) :: status

      integer :: i, n, ios, lead, n_int, n_frac, expo, first_sig
      logical :: exp_negative
      character :: c

      ! the text as it is, without a lowered copy: a file of 10^6 nodes has 3·10^6 of them
      value = 0.0_dp
      n = len(text)
      i = 1
      if (text(1:1) == '-' .or. text(1:1) == '+') i = 2
      if (i <= n) then
         c = text(i:i)
         if (c == 'n' .or. c == 'N' .or. c == 'i' .or. c == 'I') then
            if (to_lower(text(i:min(n, i + 2))) == 'nan' .or. to_lower(text(i:min(n, i + 2))) == 'inf') then
               status = 2
               return
            end if
         end if
      end if
      status = 1
      ! integer part, remembering where the first significant digit is for the magnitude
      lead = i
      first_sig = 0
      n_int = 0
      do while (i <= n)
         if (.not. is_digit(text(i:i))) exit
         if (first_sig == 0 .and. text(i:i) /= '0') first_sig = i
         n_int = n_int + 1
         i = i + 1
      end do
      n_frac = 0
      if (i <= n) then
         if (text(i:i) == '.') then
            i = i + 1
            do while (i <= n)
               if (.not. is_digit(text(i:i))) exit
               n_frac = n_frac + 1
               i = i + 1
            end do
         end if
      end if
      if (n_int + n_frac == 0) return
      expo = 0
      if (i <= n) then
         c = text(i:i)
         if (c /= 'e' .and. c /= 'E' .and. c /= 'd' .and. c /= 'D') return
         i = i + 1
         exp_negative = .false.
         if (i <= n) then
            if (text(i:i) == '-' .or. text(i:i) == '+') then
               exp_negative = text(i:i) == '-'
               i = i + 1
            end if
         end if
         if (i > n) return
         do while (i <= n)
            if (.not. is_digit(text(i:i))) return
            ! saturate: anything this large is out of range either way
            if (expo < 100000) expo = 10*expo + (iachar(text(i:i)) - iachar('0'))
            i = i + 1
         end do
         if (exp_negative) expo = -expo
      end if
      ! Small integers (z = 0 above all) are exact in dp: skip the slow library conversion.
      if (lead + n_int - 1 == n .and. n_int <= 15) then
         do i = lead, n
            value = 10*value + (iachar(text(i:i)) - iachar('0'))
         end do
         if (text(1:1) == '-') value = -value
         status = 0
         return
      end if
      ! Only an integer part with significant digits can overflow; fractions alone are below 1.
      if (first_sig > 0) then
         if (n_int - (first_sig - lead) - 1 + expo > max_exponent10) then
            status = 2
            return
         end if
      else if (expo > max_exponent10) then
         status = 2
         return
      end if
      if (decimal_value(text, value)) then
         status = 0
         return
      end if
      read (text, *, iostat=ios) value
      if (ios /= 0) then
         value = 0.0_dp
         return
      end if
      status = 0
   end subroutine parse_real

   pure logical function is_digit(c)
      character, intent(in) :: c

      is_digit = c >= '0' .and. c <= '9'
   end function is_digit
end module twomem_mesh_gmsh_text
