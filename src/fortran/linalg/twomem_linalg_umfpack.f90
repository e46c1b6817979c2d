!> Direct sparse solves with UMFPACK, the only Fortran module that knows the C glue in
!> src/c/twomem_umfpack.c. An `umfpack_solver_t` analyses a pattern once and refactors for new
!> values, which is exactly what Newton needs: the Newton matrix keeps its pattern (the
!> C-function rows carry all three diagonal entries, some of them zero) while its values change.
module twomem_linalg_umfpack
   use, intrinsic :: iso_c_binding, only: c_int, c_double, c_ptr, c_null_ptr, c_associated, c_char, c_size_t
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_system, only: c_text
   use twomem_linalg_csr, only: csr_t
   implicit none
   private

   public :: umfpack_solver_t, ordering_nested_dissection, ordering_minimum_degree, umfpack_library

   !> Fill-reducing orderings. Nested dissection (METIS) is the default: on the Newton systems,
   !> refactorized at every step, its smaller factors won (see src/c/twomem_umfpack.c). A matrix
   !> factorized once for a run may prefer minimum degree, whose analysis costs less than METIS's.
   enum, bind(c)
      enumerator :: ordering_nested_dissection = 0, ordering_minimum_degree
   end enum

   type :: umfpack_solver_t
      private
      type(c_ptr) :: handle = c_null_ptr
      integer(ip) :: n = 0
      integer(ip) :: nnz = 0
      integer :: ordering = ordering_nested_dissection
      !> at most this many steps of iterative refinement per solve (UMFPACK's default)
      integer :: refinement_steps = 2
   contains
      procedure :: set_ordering
      procedure :: set_refinement
      procedure :: factor
      procedure :: solve
      procedure :: rcond
      procedure :: free
      final :: finalize
   end type umfpack_solver_t

   interface
      integer(c_int) function twomem_umf_analyse(n, row_ptr, col, val, minimum_degree, handle) bind(C)
         import :: c_int, c_double, c_ptr
         integer(c_int), value :: n
         integer(c_int), intent(in) :: row_ptr(*), col(*)
         real(c_double), intent(in) :: val(*)
         integer(c_int), value :: minimum_degree
         type(c_ptr), intent(out) :: handle
      end function twomem_umf_analyse

      integer(c_int) function twomem_umf_factor(handle, val) bind(C)
         import :: c_int, c_double, c_ptr
         type(c_ptr), value :: handle
         real(c_double), intent(in) :: val(*)
      end function twomem_umf_factor

      integer(c_int) function twomem_umf_solve(handle, val, b, x, refinement_steps) bind(C)
         import :: c_int, c_double, c_ptr
         type(c_ptr), value :: handle
         real(c_double), intent(in) :: val(*), b(*)
         real(c_double), intent(out) :: x(*)
         integer(c_int), value :: refinement_steps
      end function twomem_umf_solve

      real(c_double) function twomem_umf_rcond(handle) bind(C)
         import :: c_double, c_ptr
         type(c_ptr), value :: handle
      end function twomem_umf_rcond

      subroutine twomem_umf_free(handle) bind(C)
         import :: c_ptr
         type(c_ptr), intent(inout) :: handle
      end subroutine twomem_umf_free

      subroutine twomem_umf_library(text, cap) bind(C)
         import :: c_char, c_size_t
         character(kind=c_char), intent(out) :: text(*)
         integer(c_size_t), value :: cap
      end subroutine twomem_umf_library
   end interface

contains

   !> UMFPACK's version and the BLAS it runs on ('5.7.9, BLAS /usr/lib/…/libblas.so.3 (OpenBLAS
   !> 0.3.21 …)'), as `--version` and the result file report it: the BLAS sets the speed of the
   !> direct method.
   function umfpack_library() result(text)
      character(len=:), allocatable :: text

      character(len=512) :: buffer

      call twomem_umf_library(buffer, len(buffer, c_size_t))
      text = c_text(buffer)
   end function umfpack_library

   !> The ordering of the next symbolic analysis (one of the ordering_* values).
   subroutine set_ordering(self, ordering)
      class(umfpack_solver_t), intent(inout) :: self
      integer, intent(in) :: ordering

      self%ordering = ordering
   end subroutine set_ordering

   !> At most `steps` steps of iterative refinement per solve (0: none). UMFPACK refines until
   !> the componentwise backward error stops falling: each step is one more product with A and
   !> one more pair of triangular solves. A well-conditioned SPD matrix (a Poisson problem) needs
   !> none for a backward error of round-off; the Newton systems keep the default.
   subroutine set_refinement(self, steps)
      class(umfpack_solver_t), intent(inout) :: self
      integer, intent(in) :: steps

      self%refinement_steps = steps
   end subroutine set_refinement

   !> Factorize `a`. The symbolic analysis is redone only when the pattern size changed; callers
   !> that change a pattern in place with the same size must call `free` first.
   subroutine factor(self, a, err)
      class(umfpack_solver_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      integer(c_int) :: status

      if (c_associated(self%handle) .and. (self%n /= a%n .or. self%nnz /= a%nnz())) call self%free()
      if (.not. c_associated(self%handle)) then
         status = twomem_umf_analyse(int(a%n, c_int), a%row_ptr, a%col, a%val, &
                                     merge(1_c_int, 0_c_int, self%ordering == ordering_minimum_degree), self%handle)
         if (status /= 0) then
            call make_error(err, exit_io, 'UMFPACK', 'symbolic analysis failed: '//status_text(status))
            return
         end if
         self%n = a%n
         self%nnz = a%nnz()
      end if
      status = twomem_umf_factor(self%handle, a%val)
      ! status 1 (UMFPACK_WARNING_singular_matrix) still leaves a factorization, but solving
      ! with it divides by zero: treat it as an error the Newton driver can report.
      if (status /= 0) then
         call make_error(err, exit_io, 'UMFPACK', 'numeric factorization failed: '//status_text(status))
      end if
   end subroutine factor

   subroutine solve(self, a, b, x, err)
      class(umfpack_solver_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: b(:)
      real(dp), intent(out) :: x(:)
      type(error_t), allocatable, intent(out) :: err

      integer(c_int) :: status

      status = twomem_umf_solve(self%handle, a%val, b, x, int(self%refinement_steps, c_int))
      if (status /= 0) call make_error(err, exit_io, 'UMFPACK', 'solve failed: '//status_text(status))
   end subroutine solve

   real(dp) function rcond(self)
      class(umfpack_solver_t), intent(in) :: self

      rcond = twomem_umf_rcond(self%handle)
   end function rcond

   subroutine free(self)
      class(umfpack_solver_t), intent(inout) :: self

      if (c_associated(self%handle)) call twomem_umf_free(self%handle)
      self%handle = c_null_ptr
      self%n = 0
      self%nnz = 0
   end subroutine free

   subroutine finalize(self)
      type(umfpack_solver_t), intent(inout) :: self

      call self%free()
   end subroutine finalize

   !> UMFPACK's status codes (umfpack.h) in words.
   function status_text(status) result(text)
      integer(c_int), intent(in) :: status
      character(len=:), allocatable :: text

      character(len=16) :: num

      write (num, '(i0)') status
      select case (status)
      case (1)
         text = 'matrix is singular (UMFPACK status 1)'
      case (-1)
         text = 'out of memory (UMFPACK status -1)'
      case (-3)
         text = 'invalid numeric object (UMFPACK status -3)'
      case (-4)
         text = 'invalid symbolic object (UMFPACK status -4)'
      case (-8)
         text = 'invalid matrix (UMFPACK status -8)'
      case default
         text = 'UMFPACK status '//trim(num)
      end select
   end function status_text
end module twomem_linalg_umfpack
