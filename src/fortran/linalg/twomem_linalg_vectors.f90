!> Threaded copies and fills of long arrays. A freshly allocated array's pages are zeroed by the
!> kernel when they are first written, and on a virtual machine that first touch costs several
!> times the copy itself (docs/performance.md, "Measuring"). Written
!> by one thread, the whole cost lands on one core while the others wait; written here, in the
!> same static row blocks as the threaded loops that later read the array, it is shared.
module twomem_linalg_vectors
   use twomem_base_kinds, only: dp, ip
   implicit none
   private

   public :: copy_into, copy_allocated, fill, threaded_from

   !> dest becomes an allocated copy of source (reallocated unless it has source's size)
   interface copy_allocated
      module procedure copy_allocated_real, copy_allocated_integer, copy_allocated_logical
   end interface copy_allocated

   !> every entry of x takes the value
   interface fill
      module procedure fill_real, fill_logical
   end interface fill

   !> Below this many entries a loop runs on one thread: the team's start costs more (every
   !> threaded loop of the code takes its `if` clause from here).
   integer(ip), parameter :: threaded_from = 4096

contains

   !> y = x, with y allocated by the caller to x's size
   subroutine copy_into(x, y)
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(x, y) private(i) schedule(static) if(size(y) > threaded_from)
      do i = 1, size(y, kind=ip)
         y(i) = x(i)
      end do
      !$omp end parallel do
   end subroutine copy_into

   subroutine copy_allocated_real(source, dest)
      real(dp), intent(in) :: source(:)
      real(dp), allocatable, intent(inout) :: dest(:)

      if (allocated(dest)) then
         if (size(dest) /= size(source)) deallocate (dest)
      end if
      if (.not. allocated(dest)) allocate (dest(size(source)))
      call copy_into(source, dest)
   end subroutine copy_allocated_real

   subroutine copy_allocated_integer(source, dest)
      integer(ip), intent(in) :: source(:)
      integer(ip), allocatable, intent(inout) :: dest(:)

      integer(ip) :: i

      if (allocated(dest)) then
         if (size(dest) /= size(source)) deallocate (dest)
      end if
      if (.not. allocated(dest)) allocate (dest(size(source)))
      !$omp parallel do default(none) shared(source, dest) private(i) schedule(static) if(size(dest) > threaded_from)
      do i = 1, size(dest, kind=ip)
         dest(i) = source(i)
      end do
      !$omp end parallel do
   end subroutine copy_allocated_integer

   subroutine copy_allocated_logical(source, dest)
      logical, intent(in) :: source(:)
      logical, allocatable, intent(inout) :: dest(:)

      integer(ip) :: i

      if (allocated(dest)) then
         if (size(dest) /= size(source)) deallocate (dest)
      end if
      if (.not. allocated(dest)) allocate (dest(size(source)))
      !$omp parallel do default(none) shared(source, dest) private(i) schedule(static) if(size(dest) > threaded_from)
      do i = 1, size(dest, kind=ip)
         dest(i) = source(i)
      end do
      !$omp end parallel do
   end subroutine copy_allocated_logical

   subroutine fill_real(x, value)
      real(dp), intent(out) :: x(:)
      real(dp), intent(in) :: value

      integer(ip) :: i

      !$omp parallel do default(none) shared(x, value) private(i) schedule(static) if(size(x) > threaded_from)
      do i = 1, size(x, kind=ip)
         x(i) = value
      end do
      !$omp end parallel do
   end subroutine fill_real

   subroutine fill_logical(x, value)
      logical, intent(out) :: x(:)
      logical, intent(in) :: value

      integer(ip) :: i

      !$omp parallel do default(none) shared(x, value) private(i) schedule(static) if(size(x) > threaded_from)
      do i = 1, size(x, kind=ip)
         x(i) = value
      end do
      !$omp end parallel do
   end subroutine fill_logical
end module twomem_linalg_vectors
