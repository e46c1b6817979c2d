!> What the fuzzer demands of every answer a parser gives. A rejection must keep the bad-input
!> contract of docs/input.md: exit category 2 and one short line that starts by naming the file
!> (or the override) it is about. An acceptance must be usable: a mesh that passes the reader
!> satisfies the invariants the solver relies on. Each function returns '' when all is well and
!> otherwise says what is wrong, so the driver can print it next to the input that caused it.
module fuzz_checks
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, exit_bad_input
   use twomem_mesh_triangulation, only: mesh_t, signed_area
   implicit none
   private

   public :: message_problem, mesh_problem

   !> A message may say this much beyond the name of what it is about: enough for any honest
   !> message, too little for one that quotes a 70 000-character token back at the user.
   integer, parameter :: max_extra = 400

contains

   !> '' if `err` is a proper bad-input error whose message starts with `prefix` (or with
   !> `alt_prefix`, when given), else what is wrong with it.
   function message_problem(err, prefix, alt_prefix) result(problem)
      type(error_t), intent(in) :: err
      character(len=*), intent(in) :: prefix
      character(len=*), intent(in), optional :: alt_prefix
      character(len=:), allocatable :: problem

      integer :: i, c, limit
      character(len=16) :: buf

      problem = ''
      if (err%code /= exit_bad_input) then
         write (buf, '(i0)') err%code
         problem = 'exit category '//trim(buf)//' instead of 2 (bad input)'
         return
      end if
      if (.not. allocated(err%message)) then
         problem = 'no message'
         return
      end if
      if (len_trim(err%message) == 0) then
         problem = 'empty message'
         return
      end if
      do i = 1, len(err%message)
         c = iachar(err%message(i:i))
         if (c < 32 .or. c == 127) then
            write (buf, '(i0)') c
            problem = 'control character '//trim(buf)//' in the message (not one clean line)'
            return
         end if
      end do
      limit = 0
      if (index(err%message, prefix) == 1) limit = len(prefix)
      if (present(alt_prefix)) then
         if (index(err%message, alt_prefix) == 1) limit = max(limit, len(alt_prefix))
      end if
      if (limit == 0) then
         problem = 'the message does not start with the name of the file'
         if (present(alt_prefix)) problem = problem//' or of the override'
         return
      end if
      if (len(err%message) > limit + max_extra) then
         write (buf, '(i0)') len(err%message)
         problem = 'message of '//trim(buf)//' characters: it quotes too much of the input'
      end if
   end function message_problem

   !> '' if `mesh` is fit for the solver: triangles with three distinct existing vertices,
   !> counter-clockwise with positive area, finite coordinates, every vertex used, every edge
   !> between one and two triangles, and a boundary.
   function mesh_problem(mesh) result(problem)
      type(mesh_t), intent(in) :: mesh
      character(len=:), allocatable :: problem

      integer(ip) :: t, e
      real(dp) :: a

      problem = ''
      if (mesh%nv < 3 .or. mesh%nt < 1) then
         problem = 'accepted a mesh with fewer than 3 vertices or no triangle'
         return
      end if
      if (size(mesh%vertices, 2) /= mesh%nv .or. size(mesh%triangles, 2) /= mesh%nt) then
         problem = 'array sizes disagree with nv, nt'
         return
      end if
      if (.not. all(ieee_is_finite(mesh%vertices))) then
         problem = 'accepted non-finite coordinates'
         return
      end if
      if (any(mesh%triangles < 1) .or. any(mesh%triangles > mesh%nv)) then
         problem = 'a triangle refers to a vertex out of range'
         return
      end if
      do t = 1, mesh%nt
         associate (v => mesh%triangles(:, t))
            if (v(1) == v(2) .or. v(2) == v(3) .or. v(1) == v(3)) then
               problem = 'a triangle repeats a vertex'
               return
            end if
            a = signed_area(mesh%vertices(:, v(1)), mesh%vertices(:, v(2)), mesh%vertices(:, v(3)))
         end associate
         if (.not. (a > 0.0_dp .and. mesh%area(t) > 0.0_dp)) then
            problem = 'a triangle is not counter-clockwise with positive area'
            return
         end if
      end do
      if (any(mesh%patch_ptr(2:) <= mesh%patch_ptr(:mesh%nv))) then
         problem = 'a vertex belongs to no triangle'
         return
      end if
      if (mesh%ne < 3) then
         problem = 'fewer than 3 edges'
         return
      end if
      do e = 1, mesh%ne
         if (mesh%edge_triangles(1, e) < 1) then
            problem = 'an edge without a triangle'
            return
         end if
      end do
      if (count(mesh%boundary_edge) < 3) problem = 'a boundary of fewer than 3 edges'
   end function mesh_problem
end module fuzz_checks
