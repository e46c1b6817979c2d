!> The communicator every distributed part of twomem works through: one private duplicate of
!> MPI_COMM_WORLD, made by the program and passed down (never a global), wrapped with the few
!> collective operations the code needs: global sums and maxima, broadcasts from rank 0,
!> gathers to rank 0 and scatters from it, and the neighbour exchange of interface values.
!> This is the MPI build's version (mpi_f08); src/fortran/base/serial/ has the same module for
!> a build without MPI, where every operation is the identity on one rank, so one rank runs
!> the same code path as many. Every reduction is deterministic for a given number of ranks
!> (MPI reduces in a fixed order), so a run repeats bit for bit. A default `comm_t` is one
!> rank: every operation then returns at once without touching MPI, which is how objects built
!> without a communicator (unit tests, whole meshes) still work.
module twomem_base_comm
   use mpi_f08, only: MPI_Comm, MPI_COMM_WORLD, MPI_Init_thread, MPI_Initialized, MPI_Finalized, MPI_Finalize, &
      MPI_Comm_dup, MPI_Comm_free, MPI_Comm_rank, MPI_Comm_size, MPI_Allreduce, MPI_Bcast, MPI_Gather, &
      MPI_Gatherv, MPI_Scatterv, MPI_Isend, MPI_Irecv, MPI_Waitall, MPI_Barrier, MPI_Request, MPI_Status, &
      MPI_IN_PLACE, MPI_SUM, MPI_MAX, MPI_MIN, MPI_LOR, MPI_DOUBLE_PRECISION, MPI_INTEGER, MPI_INTEGER8, &
      MPI_LOGICAL, MPI_CHARACTER, MPI_THREAD_FUNNELED, MPI_STATUSES_IGNORE, MPI_Abort, &
      MPI_Get_library_version, MPI_MAX_LIBRARY_VERSION_STRING
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error
   implicit none
   private

   public :: comm_t, comm_start, comm_stop, comm_abort, mpi_enabled, mpi_library

   !> this build talks MPI
   logical, parameter :: mpi_enabled = .true.

   type :: comm_t
      integer :: rank = 0, size = 1
      type(MPI_Comm) :: handle
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

   !> Start MPI (once per process) and duplicate MPI_COMM_WORLD into `comm`. A process not
   !> started by an MPI launcher (none of the variables mpirun, mpiexec or srun set is there) is
   !> one rank without MPI: Open MPI's singleton start costs most of a second, which every
   !> `twomem check` would pay; the one-rank code path is the same either way.
   subroutine comm_start(comm)
      type(comm_t), intent(out) :: comm

      logical :: started
      integer :: provided

      if (.not. launched()) return
      call MPI_Initialized(started)
      ! OpenMP threads never call MPI: only the thread that started it
      if (.not. started) call MPI_Init_thread(MPI_THREAD_FUNNELED, provided)
      call MPI_Comm_dup(MPI_COMM_WORLD, comm%handle)
      call MPI_Comm_rank(comm%handle, comm%rank)
      call MPI_Comm_size(comm%handle, comm%size)
      comm%live = .true.
   end subroutine comm_start

   !> Free the communicator and end MPI (every rank must get here before exiting).
   subroutine comm_stop(comm)
      type(comm_t), intent(inout) :: comm

      logical :: started, finalized

      call comm%free()
      call MPI_Initialized(started)
      if (.not. started) return
      call MPI_Finalized(finalized)
      if (.not. finalized) call MPI_Finalize()
   end subroutine comm_stop

   !> Whether an MPI launcher started this process (Open MPI's mpirun, MPICH's or Intel's
   !> mpiexec, Slurm's srun), or TWOMEM_MPI=1 asks for MPI anyway.
   logical function launched()
      character(len=*), parameter :: names(5) = [character(len=20) :: 'OMPI_COMM_WORLD_SIZE', 'PMI_SIZE', &
                                                 'PMIX_RANK', 'SLURM_PROCID', 'TWOMEM_MPI']
      integer :: i, length, status

      launched = .false.
      do i = 1, size(names)
         call get_environment_variable(trim(names(i)), length=length, status=status)
         if (status == 0 .and. length > 0) launched = .true.
      end do
   end function launched

   !> End every rank at once with `code`: only for a failure that one rank cannot report to
   !> the others through a collective (the program's last resort).
   subroutine comm_abort(comm, code)
      type(comm_t), intent(in) :: comm
      integer, intent(in) :: code

      call MPI_Abort(comm%handle, code)
   end subroutine comm_abort

   subroutine free(self)
      class(comm_t), intent(inout) :: self

      if (self%live) call MPI_Comm_free(self%handle)
      self%live = .false.
   end subroutine free

   pure logical function is_root(self)
      class(comm_t), intent(in) :: self

      is_root = self%rank == 0
   end function is_root

   real(dp) function sum_real(self, x) result(s)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_DOUBLE_PRECISION, MPI_SUM, self%handle)
   end function sum_real

   !> In place: x = Σ over ranks.
   subroutine sum_reals(self, x)
      class(comm_t), intent(in) :: self
      real(dp), intent(inout) :: x(:)

      if (self%size > 1) call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, MPI_SUM, self%handle)
   end subroutine sum_reals

   integer function sum_int(self, x) result(s)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_INTEGER, MPI_SUM, self%handle)
   end function sum_int

   subroutine sum_ints(self, x)
      class(comm_t), intent(in) :: self
      integer, intent(inout) :: x(:)

      if (self%size > 1) call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_INTEGER, MPI_SUM, self%handle)
   end subroutine sum_ints

   integer(i8) function sum_int8(self, x) result(s)
      class(comm_t), intent(in) :: self
      integer(i8), intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_INTEGER8, MPI_SUM, self%handle)
   end function sum_int8

   real(dp) function max_real(self, x) result(s)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_DOUBLE_PRECISION, MPI_MAX, self%handle)
   end function max_real

   integer function max_int(self, x) result(s)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_INTEGER, MPI_MAX, self%handle)
   end function max_int

   real(dp) function min_real(self, x) result(s)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_DOUBLE_PRECISION, MPI_MIN, self%handle)
   end function min_real

   logical function any_true(self, x) result(s)
      class(comm_t), intent(in) :: self
      logical, intent(in) :: x

      if (self%size == 1) then
         s = x
         return
      end if
      call MPI_Allreduce(x, s, 1, MPI_LOGICAL, MPI_LOR, self%handle)
   end function any_true

   subroutine bcast_int(self, x)
      class(comm_t), intent(in) :: self
      integer, intent(inout) :: x

      if (self%size > 1) call MPI_Bcast(x, 1, MPI_INTEGER, 0, self%handle)
   end subroutine bcast_int

   subroutine bcast_logical(self, x)
      class(comm_t), intent(in) :: self
      logical, intent(inout) :: x

      if (self%size > 1) call MPI_Bcast(x, 1, MPI_LOGICAL, 0, self%handle)
   end subroutine bcast_logical

   !> Broadcast an allocatable array from rank 0; other ranks get it allocated to its size.
   subroutine bcast_ints(self, x)
      class(comm_t), intent(in) :: self
      integer(ip), allocatable, intent(inout) :: x(:)

      integer :: n

      if (self%size == 1) return

      n = 0
      if (self%rank == 0) n = size(x)
      call MPI_Bcast(n, 1, MPI_INTEGER, 0, self%handle)
      if (self%rank /= 0) then
         if (allocated(x)) deallocate (x)
         allocate (x(n))
      end if
      if (n > 0) call MPI_Bcast(x, n, MPI_INTEGER, 0, self%handle)
   end subroutine bcast_ints

   subroutine bcast_ints2(self, x)
      class(comm_t), intent(in) :: self
      integer(ip), allocatable, intent(inout) :: x(:, :)

      integer :: shape_(2)

      if (self%size == 1) return

      shape_ = 0
      if (self%rank == 0) shape_ = shape(x)
      call MPI_Bcast(shape_, 2, MPI_INTEGER, 0, self%handle)
      if (self%rank /= 0) then
         if (allocated(x)) deallocate (x)
         allocate (x(shape_(1), shape_(2)))
      end if
      if (product(shape_) > 0) call MPI_Bcast(x, product(shape_), MPI_INTEGER, 0, self%handle)
   end subroutine bcast_ints2

   subroutine bcast_reals(self, x)
      class(comm_t), intent(in) :: self
      real(dp), allocatable, intent(inout) :: x(:)

      integer :: n

      if (self%size == 1) return

      n = 0
      if (self%rank == 0) n = size(x)
      call MPI_Bcast(n, 1, MPI_INTEGER, 0, self%handle)
      if (self%rank /= 0) then
         if (allocated(x)) deallocate (x)
         allocate (x(n))
      end if
      if (n > 0) call MPI_Bcast(x, n, MPI_DOUBLE_PRECISION, 0, self%handle)
   end subroutine bcast_reals

   subroutine bcast_reals2(self, x)
      class(comm_t), intent(in) :: self
      real(dp), allocatable, intent(inout) :: x(:, :)

      integer :: shape_(2)

      if (self%size == 1) return

      shape_ = 0
      if (self%rank == 0) shape_ = shape(x)
      call MPI_Bcast(shape_, 2, MPI_INTEGER, 0, self%handle)
      if (self%rank /= 0) then
         if (allocated(x)) deallocate (x)
         allocate (x(shape_(1), shape_(2)))
      end if
      if (product(shape_) > 0) call MPI_Bcast(x, product(shape_), MPI_DOUBLE_PRECISION, 0, self%handle)
   end subroutine bcast_reals2

   subroutine bcast_text(self, text)
      class(comm_t), intent(in) :: self
      character(len=:), allocatable, intent(inout) :: text

      integer :: n

      if (self%size == 1) return

      n = 0
      if (self%rank == 0) n = len(text)
      call MPI_Bcast(n, 1, MPI_INTEGER, 0, self%handle)
      if (self%rank /= 0) then
         if (allocated(text)) deallocate (text)
         allocate (character(len=n) :: text)
      end if
      if (n > 0) call MPI_Bcast(text, n, MPI_CHARACTER, 0, self%handle)
   end subroutine bcast_text

   !> The count n of every rank, on rank 0 (an empty array elsewhere).
   subroutine gather_counts(self, n, counts)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: n
      integer, allocatable, intent(out) :: counts(:)

      allocate (counts(merge(self%size, 0, self%rank == 0)))
      if (self%size == 1) then
         counts = n
         return
      end if
      call MPI_Gather(n, 1, MPI_INTEGER, counts, 1, MPI_INTEGER, 0, self%handle)
   end subroutine gather_counts

   !> Concatenate every rank's `x` on rank 0 in rank order; `counts` from `gather_counts`.
   subroutine gatherv_reals(self, x, counts, all)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      integer, intent(in) :: counts(:)
      real(dp), intent(out) :: all(:)

      if (self%size == 1) then
         all = x
         return
      end if
      call MPI_Gatherv(x, size(x), MPI_DOUBLE_PRECISION, all, counts, displacements(counts), MPI_DOUBLE_PRECISION, &
                       0, self%handle)
   end subroutine gatherv_reals

   subroutine gatherv_ints(self, x, counts, all)
      class(comm_t), intent(in) :: self
      integer(ip), intent(in) :: x(:)
      integer, intent(in) :: counts(:)
      integer(ip), intent(out) :: all(:)

      if (self%size == 1) then
         all = x
         return
      end if
      call MPI_Gatherv(x, size(x), MPI_INTEGER, all, counts, displacements(counts), MPI_INTEGER, 0, self%handle)
   end subroutine gatherv_ints

   !> The inverse of gatherv_reals: rank 0's `all`, in rank order, split into each rank's `x`.
   subroutine scatterv_reals(self, all, counts, x)
      class(comm_t), intent(in) :: self
      real(dp), intent(in) :: all(:)
      integer, intent(in) :: counts(:)
      real(dp), intent(out) :: x(:)

      if (self%size == 1) then
         x = all
         return
      end if
      call MPI_Scatterv(all, counts, displacements(counts), MPI_DOUBLE_PRECISION, x, size(x), MPI_DOUBLE_PRECISION, &
                        0, self%handle)
   end subroutine scatterv_reals

   pure function displacements(counts) result(displs)
      integer, intent(in) :: counts(:)
      integer :: displs(size(counts))

      integer :: i

      if (size(counts) == 0) return
      displs(1) = 0
      do i = 2, size(counts)
         displs(i) = displs(i - 1) + counts(i - 1)
      end do
   end function displacements

   !> Point-to-point exchange with the neighbour ranks: send(send_ptr(k):send_ptr(k+1)-1) goes
   !> to neighbours(k), whose message lands in recv(recv_ptr(k):recv_ptr(k+1)-1). Both sides
   !> must agree on the sizes (they are built from the same shared lists).
   subroutine exchange(self, neighbours, send, send_ptr, recv, recv_ptr)
      class(comm_t), intent(in) :: self
      integer, intent(in) :: neighbours(:)
      real(dp), intent(in), contiguous, asynchronous :: send(:)
      integer, intent(in) :: send_ptr(:), recv_ptr(:)
      real(dp), intent(inout), contiguous, asynchronous :: recv(:)

      type(MPI_Request) :: requests(2*size(neighbours))
      integer :: k, n

      n = size(neighbours)
      if (n == 0) return
      do k = 1, n
         call MPI_Irecv(recv(recv_ptr(k):), recv_ptr(k + 1) - recv_ptr(k), MPI_DOUBLE_PRECISION, neighbours(k), 7, &
                        self%handle, requests(k))
      end do
      do k = 1, n
         call MPI_Isend(send(send_ptr(k):), send_ptr(k + 1) - send_ptr(k), MPI_DOUBLE_PRECISION, neighbours(k), 7, &
                        self%handle, requests(n + k))
      end do
      call MPI_Waitall(2*n, requests, MPI_STATUSES_IGNORE)
   end subroutine exchange

   !> After a step that may fail on some ranks only: every rank leaves with the error of the
   !> lowest failing rank (code and message), or with none. Collective.
   subroutine agree(self, err)
      class(comm_t), intent(in) :: self
      type(error_t), allocatable, intent(inout) :: err

      integer :: mine, first, code, n
      character(len=:), allocatable :: message

      if (self%size == 1) return
      mine = merge(self%rank, self%size, allocated(err))
      call MPI_Allreduce(mine, first, 1, MPI_INTEGER, MPI_MIN, self%handle)
      if (first == self%size) return
      code = 0
      n = 0
      if (self%rank == first) then
         code = err%code
         message = err%message
         n = len(message)
      end if
      call MPI_Bcast(code, 1, MPI_INTEGER, first, self%handle)
      call MPI_Bcast(n, 1, MPI_INTEGER, first, self%handle)
      if (self%rank /= first) allocate (character(len=n) :: message)
      if (n > 0) call MPI_Bcast(message, n, MPI_CHARACTER, first, self%handle)
      if (allocated(err)) deallocate (err)
      call make_error(err, code, '', message)
   end subroutine agree

   subroutine barrier(self)
      class(comm_t), intent(in) :: self

      if (self%size > 1) call MPI_Barrier(self%handle)
   end subroutine barrier
   !> The MPI library this build runs on, as `--version` reports it (callable before comm_start:
   !> users checking a cluster's module set want to see which MPI they got).
   function mpi_library() result(text)
      character(len=:), allocatable :: text
      character(len=MPI_MAX_LIBRARY_VERSION_STRING) :: version
      integer :: length, ierr, eol

      call MPI_Get_library_version(version, length, ierr)
      text = version(:length)
      eol = scan(text, achar(10)//',')
      if (eol > 1) text = text(:eol - 1)
   end function mpi_library

end module twomem_base_comm
