!> The namelist syntax, without knowing any group or key. We read case files ourselves instead of
!> with `read(unit, nml=...)` because the intrinsic reader reports neither the line nor the key of
!> a bad value and silently skips text before a group. Here a file becomes a list of groups, each
!> a list of `key = value` assignments that keep their line number and their raw value text;
!> `twomem_input_values` converts the values and `twomem_input_config` knows what the keys mean.
module twomem_input_namelist
   use twomem_base_errors, only: error_t, make_error, exit_bad_input, excerpt
   use twomem_input_values, only: quote, scan_quoted
   use twomem_base_text, only: int_text, to_lower
   implicit none
   private

   public :: string_t, nml_assignment_t, nml_group_t
   public :: read_lines, split_lines, parse_namelist
   public :: line_where

   !> A string of any length, so that arrays of command-line words need no fixed width.
   type :: string_t
      character(len=:), allocatable :: s
   end type string_t

   !> One `key = value`; `value` is already unquoted when `quoted` is set.
   type :: nml_assignment_t
      character(len=:), allocatable :: key
      character(len=:), allocatable :: value
      logical :: quoted = .false.
      integer :: line = 0
   end type nml_assignment_t

   type :: nml_group_t
      character(len=:), allocatable :: name
      integer :: line = 0
      integer :: n = 0
      type(nml_assignment_t), allocatable :: assignments(:)
   end type nml_group_t

   integer, parameter :: tk_group_start = 1, tk_group_end = 2, tk_equals = 3, tk_comma = 4, &
                         tk_string = 5, tk_bare = 6, tk_error = 7

   type :: token_t
      integer :: kind = 0
      character(len=:), allocatable :: text
      integer :: line = 0
   end type token_t

   character(len=*), parameter :: blanks = ' '//achar(9)//achar(13)

   !> Far more groups and assignments than any case has. Duplicates are found by comparing each
   !> name with those before it; without a bound, a file of 60 000 groups took minutes.
   integer, parameter :: max_groups = 100, max_assignments = 200

   character(len=*), parameter :: unexpected_hint = &
      " (expected 'key = value'; arrays and multiple values are not supported)"

contains

   !> All lines of a text file, of any length. A missing or unreadable file is bad input (2):
   !> the user named it.
   subroutine read_lines(path, lines, err)
      character(len=*), intent(in) :: path
      type(string_t), allocatable, intent(out) :: lines(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=512) :: msg
      character(len=256) :: buf
      character(len=:), allocatable :: line
      integer :: unit, ios, n, size_read, used
      logical :: is_dir

      allocate (lines(0))
      ! a directory opens and reads as an empty file; 'dir/.' exists only for a directory
      inquire (file=path//'/.', exist=is_dir)
      if (is_dir .and. len(path) > 0) then
         call make_error(err, exit_bad_input, path, 'is a directory, not an input file')
         return
      end if
      open (newunit=unit, file=path, status='old', action='read', form='formatted', &
            access='sequential', iostat=ios, iomsg=msg)
      if (ios /= 0) then
         call make_error(err, exit_bad_input, path, 'cannot open the input file ('//trim(msg)//')')
         return
      end if
      n = 0
      allocate (character(len=len(buf)) :: line)
      outer: do
         used = 0
         do
            read (unit, '(a)', advance='no', size=size_read, iostat=ios, iomsg=msg) buf
            if (ios == 0 .or. is_iostat_eor(ios)) call append(line, used, buf(1:size_read))
            if (is_iostat_eor(ios)) exit
            if (is_iostat_end(ios)) then
               ! a last line without a newline whose length is a multiple of the chunk ends
               ! in a full chunk and then the end of the file, not in an end of record
               if (used > 0) then
                  n = n + 1
                  call push_line(lines, n, line(1:used))
               end if
               exit outer
            end if
            if (ios /= 0) then
               call make_error(err, exit_bad_input, path, 'cannot read the input file ('//trim(msg)//')')
               close (unit)
               return
            end if
         end do
         n = n + 1
         call push_line(lines, n, line(1:used))
      end do outer
      close (unit)
      lines = lines(1:n)
   end subroutine read_lines

   !> Append `piece` to text(1:used), doubling the buffer when it is full: a line read in short
   !> chunks costs linear time however long it is (a binary file has megabytes between newlines).
   subroutine append(text, used, piece)
      character(len=:), allocatable, intent(inout) :: text
      integer, intent(inout) :: used
      character(len=*), intent(in) :: piece

      character(len=:), allocatable :: wider

      if (used + len(piece) > len(text)) then
         allocate (character(len=2*(used + len(piece))) :: wider)
         wider(1:used) = text(1:used)
         call move_alloc(wider, text)
      end if
      text(used + 1:used + len(piece)) = piece
      used = used + len(piece)
   end subroutine append

   !> Lines of a text held in memory (e.g. the `input` attribute of a result file), split as the
   !> run-time library splits a file: at LF, at CR LF and at a lone CR.
   subroutine split_lines(text, lines)
      character(len=*), intent(in) :: text
      type(string_t), allocatable, intent(out) :: lines(:)

      character, parameter :: lf = achar(10), cr = achar(13)
      integer :: start, k, n

      allocate (lines(0))
      n = 0
      start = 1
      k = 1
      do while (k <= len(text))
         if (text(k:k) == lf .or. text(k:k) == cr) then
            n = n + 1
            call push_line(lines, n, text(start:k - 1))
            if (text(k:k) == cr .and. k < len(text)) then
               if (text(k + 1:k + 1) == lf) k = k + 1
            end if
            start = k + 1
         end if
         k = k + 1
      end do
      if (start <= len(text)) then
         n = n + 1
         call push_line(lines, n, text(start:))
      end if
      lines = lines(1:n)
   end subroutine split_lines

   subroutine push_line(lines, n, line)
      type(string_t), allocatable, intent(inout) :: lines(:)
      integer, intent(in) :: n
      character(len=*), intent(in) :: line

      type(string_t), allocatable :: tmp(:)
      integer :: i

      if (n > size(lines)) then
         allocate (tmp(max(16, 2*size(lines))))
         do i = 1, size(lines)
            call move_alloc(lines(i)%s, tmp(i)%s)
         end do
         call move_alloc(tmp, lines)
      end if
      lines(n)%s = line
   end subroutine push_line

   !> `<file>:<line>`, the start of every located message.
   function line_where(file, line) result(where)
      character(len=*), intent(in) :: file
      integer, intent(in) :: line
      character(len=:), allocatable :: where

      character(len=16) :: buf

      write (buf, '(i0)') line
      where = file//':'//trim(buf)
   end function line_where

   !> Split the text into groups of assignments. Only the syntax is checked here (and that no
   !> group or key appears twice, which needs no knowledge of the keys); `file` names the source
   !> in messages.
   subroutine parse_namelist(lines, file, groups, err)
      type(string_t), intent(in) :: lines(:)
      character(len=*), intent(in) :: file
      type(nml_group_t), allocatable, intent(out) :: groups(:)
      type(error_t), allocatable, intent(out) :: err

      type(token_t), allocatable :: t(:)
      integer :: n, i, ng, j

      call tokenize(lines, t, n)
      allocate (groups(0))
      ng = 0
      i = 1
      do while (i <= n)
         select case (t(i)%kind)
         case (tk_error)
            call make_error(err, exit_bad_input, line_where(file, t(i)%line), t(i)%text)
            return
         case (tk_group_start)
            do j = 1, ng
               if (groups(j)%name == t(i)%text) then
                  call make_error(err, exit_bad_input, line_where(file, t(i)%line)//': &'//excerpt(t(i)%text), &
                                  'group given twice (first at line '//int_text(groups(j)%line)//')')
                  return
               end if
            end do
            if (ng == max_groups) then
               call make_error(err, exit_bad_input, line_where(file, t(i)%line), &
                               'more than '//int_text(max_groups)//' groups: not a case file')
               return
            end if
            ng = ng + 1
            call push_group(groups, ng, t(i)%text, t(i)%line)
            i = i + 1
            call parse_group(t, n, i, file, groups(ng), err)
            if (allocated(err)) return
         case default
            call make_error(err, exit_bad_input, line_where(file, t(i)%line), &
                            'stray text outside groups: '//quote(excerpt(t(i)%text))//" (a group is '&name ... /')")
            return
         end select
      end do
      do j = 1, ng
         groups(j)%assignments = groups(j)%assignments(1:groups(j)%n)
      end do
      groups = groups(1:ng)
   end subroutine parse_namelist

   !> The assignments of `group` from token `i` (just after `&name`) to its closing `/`; `i` ends
   !> on the token after it.
   subroutine parse_group(t, n, i, file, group, err)
      type(token_t), intent(in) :: t(:)
      integer, intent(in) :: n
      integer, intent(inout) :: i
      character(len=*), intent(in) :: file
      type(nml_group_t), intent(inout) :: group
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: key, ctx, here
      integer :: j

      ctx = ': &'//excerpt(group%name)
      do
         if (i > n) then
            call make_error(err, exit_bad_input, line_where(file, group%line)//ctx, &
                            "missing '/' at the end of the group (reached the end of the file)")
            return
         end if
         here = line_where(file, t(i)%line)//ctx
         select case (t(i)%kind)
         case (tk_error)
            call make_error(err, exit_bad_input, here, t(i)%text)
            return
         case (tk_group_end)
            i = i + 1
            return
         case (tk_comma)
            i = i + 1
         case (tk_group_start)
            call make_error(err, exit_bad_input, here, "missing '/' at the end of the group before &"//excerpt(t(i)%text))
            return
         case (tk_equals)
            call make_error(err, exit_bad_input, here, "'=' without a key")
            return
         case (tk_string)
            call make_error(err, exit_bad_input, here, 'unexpected value '//quote(excerpt(t(i)%text))//unexpected_hint)
            return
         case (tk_bare)
            key = to_lower(t(i)%text)
            if (.not. is_name(key)) then
               if (index(key, '(') > 0) then
                  call make_error(err, exit_bad_input, here//': '//excerpt(key), 'array elements and substrings are not supported')
               else
                  call make_error(err, exit_bad_input, here, 'unexpected value '//quote(excerpt(t(i)%text))//unexpected_hint)
               end if
               return
            end if
            if (i == n) then
               call make_error(err, exit_bad_input, here//': '//excerpt(key), "expected '=' after the key")
               return
            else if (t(i + 1)%kind /= tk_equals) then
               call make_error(err, exit_bad_input, here//': '//excerpt(key), "expected '=' after the key")
               return
            end if
            if (group%n == max_assignments) then
               call make_error(err, exit_bad_input, here, 'more than '//int_text(max_assignments)// &
                               ' assignments in one group: not a case file')
               return
            end if
            do j = 1, group%n
               if (group%assignments(j)%key == key) then
                  call make_error(err, exit_bad_input, here//': '//excerpt(key), 'key given twice in the group (first at line ' &
                                  //int_text(group%assignments(j)%line)//')')
                  return
               end if
            end do
            call take_value(t, n, i + 2, file, ctx//': '//excerpt(key), group, key, t(i)%line, err)
            if (allocated(err)) return
            i = i + 3
         end select
      end do
   end subroutine parse_group

   !> The value of an assignment at token `i`. A key followed by '=' is the next assignment, not a
   !> value: that is how `a = ` before `b = 1` is seen as a missing value.
   subroutine take_value(t, n, i, file, ctx, group, key, key_line, err)
      type(token_t), intent(in) :: t(:)
      integer, intent(in) :: n, i
      character(len=*), intent(in) :: file, ctx
      type(nml_group_t), intent(inout) :: group
      character(len=*), intent(in) :: key
      integer, intent(in) :: key_line
      type(error_t), allocatable, intent(out) :: err

      type(nml_assignment_t) :: a
      logical :: missing

      missing = i > n
      if (.not. missing) then
         missing = .not. (t(i)%kind == tk_string .or. t(i)%kind == tk_bare)
         if (t(i)%kind == tk_error) then
            call make_error(err, exit_bad_input, line_where(file, t(i)%line)//ctx, t(i)%text)
            return
         end if
         if (t(i)%kind == tk_bare .and. i < n) then
            missing = t(i + 1)%kind == tk_equals
         end if
      end if
      if (missing) then
         call make_error(err, exit_bad_input, line_where(file, key_line)//ctx, "missing value after '='")
         return
      end if
      if (t(i)%kind == tk_bare .and. index(t(i)%text, '*') > 0) then
         call make_error(err, exit_bad_input, line_where(file, t(i)%line)//ctx, &
                         'repeat counts (r*value) are not supported (quote a formula: f1 = ''2*x''), got '// &
                         quote(excerpt(t(i)%text)))
         return
      end if
      a%key = key
      a%value = t(i)%text
      a%quoted = t(i)%kind == tk_string
      a%line = key_line
      group%n = group%n + 1
      call push_assignment(group, a)
   end subroutine take_value

   !> Tokens of the whole text. On a lexical error the last token is `tk_error` carrying the
   !> message, so the parser can add the group and key it is in.
   subroutine tokenize(lines, t, n)
      type(string_t), intent(in) :: lines(:)
      type(token_t), allocatable, intent(out) :: t(:)
      integer, intent(out) :: n

      integer :: il, p, q, m
      character(len=:), allocatable :: s, word
      character :: c

      allocate (t(64))
      n = 0
      do il = 1, size(lines)
         s = lines(il)%s
         m = len(s)
         p = 1
         do while (p <= m)
            c = s(p:p)
            if (index(blanks, c) > 0) then
               p = p + 1
            else if (c == '!') then
               exit
            else if (c == ',') then
               call push_token(t, n, tk_comma, ',', il)
               p = p + 1
            else if (c == '=') then
               call push_token(t, n, tk_equals, '=', il)
               p = p + 1
            else if (c == '/') then
               call push_token(t, n, tk_group_end, '/', il)
               p = p + 1
            else if (c == '&' .or. c == '$') then
               q = p + 1
               do while (q <= m)
                  if (.not. is_name_char(s(q:q))) exit
                  q = q + 1
               end do
               if (q == p + 1) then
                  call push_token(t, n, tk_error, "expected a group name after '"//c//"'", il)
                  return
               else if (to_lower(s(p + 1:q - 1)) == 'end') then
                  call push_token(t, n, tk_group_end, c//'end', il)
               else
                  call push_token(t, n, tk_group_start, to_lower(s(p + 1:q - 1)), il)
               end if
               p = q
            else if (c == "'" .or. c == '"') then
               call scan_quoted(s, p, word, q)
               if (q == 0) then
                  call push_token(t, n, tk_error, 'unterminated string (a string ends on its line)', il)
                  return
               end if
               call push_token(t, n, tk_string, word, il)
               p = q + 1
            else
               q = p
               do while (q <= m)
                  if (index(blanks//',=!', s(q:q)) > 0) exit
                  if (s(q:q) == '/' .and. ends_group(s, q)) exit
                  q = q + 1
               end do
               call push_token(t, n, tk_bare, s(p:q - 1), il)
               p = q
            end if
         end do
      end do
   end subroutine tokenize

   !> Whether the '/' at `q`, met inside a bare value, closes the group. Only when nothing but a
   !> separator follows: `levels = 3/` ends the group, while `file = out/a.h5` stays one path.
   pure logical function ends_group(s, q)
      character(len=*), intent(in) :: s
      integer, intent(in) :: q

      ends_group = q == len(s)
      if (.not. ends_group) ends_group = index(blanks//',!&$/', s(q + 1:q + 1)) > 0
   end function ends_group

   subroutine push_token(t, n, kind, text, line)
      type(token_t), allocatable, intent(inout) :: t(:)
      integer, intent(inout) :: n
      integer, intent(in) :: kind, line
      character(len=*), intent(in) :: text

      type(token_t), allocatable :: tmp(:)
      integer :: i

      if (n == size(t)) then
         allocate (tmp(2*size(t)))
         do i = 1, n
            tmp(i)%kind = t(i)%kind
            tmp(i)%line = t(i)%line
            call move_alloc(t(i)%text, tmp(i)%text)
         end do
         call move_alloc(tmp, t)
      end if
      n = n + 1
      t(n)%kind = kind
      t(n)%text = text
      t(n)%line = line
   end subroutine push_token

   subroutine push_group(groups, n, name, line)
      type(nml_group_t), allocatable, intent(inout) :: groups(:)
      integer, intent(in) :: n, line
      character(len=*), intent(in) :: name

      type(nml_group_t), allocatable :: tmp(:)
      integer :: i

      if (n > size(groups)) then
         allocate (tmp(max(8, 2*size(groups))))
         do i = 1, size(groups)
            call move_group(groups(i), tmp(i))
         end do
         call move_alloc(tmp, groups)
      end if
      groups(n)%name = name
      groups(n)%line = line
      groups(n)%n = 0
      allocate (groups(n)%assignments(8))
   end subroutine push_group

   subroutine move_group(from, to)
      type(nml_group_t), intent(inout) :: from
      type(nml_group_t), intent(inout) :: to

      call move_alloc(from%name, to%name)
      to%line = from%line
      to%n = from%n
      call move_alloc(from%assignments, to%assignments)
   end subroutine move_group

   !> Append `a` as assignment number `group%n` (already incremented).
   subroutine push_assignment(group, a)
      type(nml_group_t), intent(inout) :: group
      type(nml_assignment_t), intent(in) :: a

      type(nml_assignment_t), allocatable :: tmp(:)
      integer :: i

      if (group%n > size(group%assignments)) then
         allocate (tmp(2*size(group%assignments)))
         do i = 1, size(group%assignments)
            call move_alloc(group%assignments(i)%key, tmp(i)%key)
            call move_alloc(group%assignments(i)%value, tmp(i)%value)
            tmp(i)%quoted = group%assignments(i)%quoted
            tmp(i)%line = group%assignments(i)%line
         end do
         call move_alloc(tmp, group%assignments)
      end if
      group%assignments(group%n) = a
   end subroutine push_assignment

   pure logical function is_name_char(c)
      character, intent(in) :: c

      is_name_char = index('abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_', c) > 0
   end function is_name_char

   !> A Fortran name: a letter, then letters, digits and underscores.
   pure logical function is_name(s)
      character(len=*), intent(in) :: s

      integer :: i

      is_name = .false.
      if (len(s) == 0) return
      if (index('abcdefghijklmnopqrstuvwxyz', s(1:1)) == 0) return
      do i = 2, len(s)
         if (.not. is_name_char(s(i:i))) return
      end do
      is_name = .true.
   end function is_name
end module twomem_input_namelist
