!> The communicator of a build without MPI (-DTWOMEM_WITH_MPI=OFF): the same module as
!> src/fortran/base/mpi/twomem_base_comm.f90, for exactly one rank, where every collective is
!> the identity. Code written against it is the distributed code path with one rank, so the
!> two builds cannot drift apart.
module twomem_base_comm
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error
   use twomem_base_system, only: exit_program
   implicit none
   private

   public :: comm_t, comm_start, comm_stop, comm_abort, mpi_enabled, mpi_library

   !> this build has no MPI
   logical, parameter :: mpi_enabled = .false.

   type :: comm_t
      integer :: rank = 0, size = 1
      logical :: live = .false.
   contains
      procedure :: is_root
      procedure :: sum_real, sum_reals, sum_int, sum_ints, sum_int8
      !> sums of scalars (functions) and of arrays in place (subroutines)
      generic :: sum => sum_real, sum_int, sum_int8
      generic :: sum_in_place => sum_reals, sum_ints
      procedure :: max_real, max_int
      generic :: max => max_real, max_int
      procedure :: min_real
      procedure :: any_true
      procedure :: bcast_int, bcast_ints, bcast_reals, bcast_reals2, bcast_ints2, bcast_text, bcast_logical
      generic :: bcast => bcast_int, bcast_ints, bcast_reals, bcast_reals2, bcast_ints2, bcast_text, bcast_logical
      procedure :: gather_counts
      procedure :: gatherv_reals, gatherv_ints
      generic :: gatherv => gatherv_reals, gatherv_ints
      procedure :: scatterv_reals
      procedure :: exchange
      procedure :: barrier
      procedure :: agree
      procedure :: free
   end type comm_t

contains

   subroutine comm_start(comm)
      type(comm_t), intent(out) :: comm

      comm%live = .true.
   end subroutine comm_start

   subroutine comm_stop(comm)
      type(comm_t), intent(inout) :: comm

      comm%live = .false.
   end subroutine comm_stop

   subroutine comm_abort(comm, code)
      type(comm_t), intent(in) :: comm
      integer, intent(in) :: code

      call exit_program(code)
   end subroutine comm_abort

   subroutine free(self)
      class(comm_t), intent(inout) :: self

      self%live = .false.
   end subroutine free

   pure logical function is_root(self)
      class(comm_t), intent(in) :: self

      is_root = .true.
   end function is_root

   real(dp) function sum_real(self, x) result(s)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x

      s = x
   end function sum_real

   subroutine sum_reals(self, x)
      class(comm_t), intent(in) :: self
      real(dp), intent(inout) :: x(:)
   end subroutine sum_reals

   integer function sum_int(self, x) result(s)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: x

      s = x
   end function sum_int

   subroutine sum_ints(self, x)
      class(comm_t), intent(in) :: self
      integer, intent(inout) :: x(:)
   end subroutine sum_ints

   integer(i8) function sum_int8(self, x) result(s)
      class(comm_t), intent(in) :: self
      integer(i8), intent(in) :: x

      s = x
   end function sum_int8

   real(dp) function max_real(self, x) result(s)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x

      s = x
   end function max_real

   integer function max_int(self, x) result(s)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: x

      s = x
   end function max_int

   real(dp) function min_real(self, x) result(s)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x

      s = x
   end function min_real

   logical function any_true(self, x) result(s)
      class(comm_t), intent(in) :: self
      logical, intent(in) :: x

      s = x
   end function any_true

   subroutine bcast_int(self, x)
      class(comm_t), intent(in) :: self
      integer, intent(inout) :: x
   end subroutine bcast_int

   subroutine bcast_logical(self, x)
      class(comm_t), intent(in) :: self
      logical, intent(inout) :: x
   end subroutine bcast_logical

   subroutine bcast_ints(self, x)
      class(comm_t), intent(in) :: self
      integer(ip), allocatable, intent(inout) :: x(:)
   end subroutine bcast_ints

   subroutine bcast_ints2(self, x)
      class(comm_t), intent(in) :: self
      integer(ip), allocatable, intent(inout) :: x(:, :)
   end subroutine bcast_ints2

   subroutine bcast_reals(self, x)
      class(comm_t), intent(in) :: self
      real(dp), allocatable, intent(inout) :: x(:)
   end subroutine bcast_reals

   subroutine bcast_reals2(self, x)
      class(comm_t), intent(in) :: self
      real(dp), allocatable, intent(inout) :: x(:, :)
   end subroutine bcast_reals2

   subroutine bcast_text(self, text)
      class(comm_t), intent(in) :: self
      character(len=:), allocatable, intent(inout) :: text
   end subroutine bcast_text

   subroutine gather_counts(self, n, counts)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: n
      integer, allocatable, intent(out) :: counts(:)

      allocate (counts(1))
      counts = n
   end subroutine gather_counts

   subroutine gatherv_reals(self, x, counts, all)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      integer, intent(in) :: counts(:)
      real(dp), intent(out) :: all(:)

      all = x
   end subroutine gatherv_reals

   subroutine gatherv_ints(self, x, counts, all)
      class(comm_t), intent(in) :: self
      integer(ip), intent(in) :: x(:)
      integer, intent(in) :: counts(:)
      integer(ip), intent(out) :: all(:)

      all = x
   end subroutine gatherv_ints

   subroutine scatterv_reals(self, all, counts, x)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: all(:)
      integer, intent(in) :: counts(:)
      real(dp), intent(out) :: x(:)

      x = all
   end subroutine scatterv_reals

   !> One rank has no neighbours: nothing to send or receive.
   subroutine exchange(self, neighbours, send, send_ptr, recv, recv_ptr)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: neighbours(:)
      real(dp), intent(in), contiguous :: send(:)
      integer, intent(in) :: send_ptr(:), recv_ptr(:)
      real(dp), intent(inout), contiguous :: recv(:)
   end subroutine exchange

   !> One rank agrees with itself.
   subroutine agree(self, err)
      class(comm_t), intent(in) :: self
      type(error_t), allocatable, intent(inout) :: err
   end subroutine agree

   subroutine barrier(self)
      class(comm_t), intent(in) :: self
   end subroutine barrier
   !> What `--version` says about MPI in a build without it.
   function mpi_library() result(text)
      character(len=:), allocatable :: text

      text = 'none (built with TWOMEM_WITH_MPI=OFF: one process)'
   end function mpi_library

end module twomem_base_comm
