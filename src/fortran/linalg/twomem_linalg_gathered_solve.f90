!> A direct solve of a distributed sparse system on rank 0: every rank holds its part of the
!> matrix (rows of the unknowns it touches, assembled over its own triangles, so the parts of a
!> shared row add up), numbered locally, with a global key of each local unknown (any distinct
!> integers, e.g. whole-mesh vertex numbers; rank 0 numbers the keys it receives). `factor`
!> gathers the entries to rank 0, which adds them into the whole matrix and factorizes it with
!> UMFPACK; `solve` gathers the right-hand side (each entry from its owner), solves on rank 0 and
!> sends every rank the values of its unknowns. This serves the coarsest multigrid level (a few
!> thousand unknowns) and the exact method (`newton.linear = 'direct'`) in distributed runs, where
!> it is only as scalable as one rank's memory: documented as such. With one rank it is UMFPACK on
!> the rank's own matrix, entries in the same order, so the factorization is the serial one.
module twomem_linalg_gathered_solve
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_comm, only: comm_t
   use twomem_base_sort, only: sort_ints
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_umfpack, only: umfpack_solver_t
   implicit none
   private

   public :: gathered_solver_t

   type :: gathered_solver_t
      type(comm_t) :: comm
      !> global key of every local unknown, and which local unknowns this rank owns
      integer(ip), allocatable :: global(:)
      logical, allocatable :: owned(:)
      !> rank 0: the keys in ascending order (the whole system's numbering is the position in
      !> it), the whole matrix and its factorization, and for every rank the whole numbers of
      !> its unknowns and of its owned ones (concatenated in rank order, counts per rank)
      integer(ip), allocatable :: keys(:)
      type(csr_t) :: whole
      type(umfpack_solver_t) :: direct
      integer, allocatable :: counts(:), owned_counts(:)
      integer(ip), allocatable :: all_global(:), all_owned_global(:)
      integer(ip) :: n_global = 0
      !> positions of each gathered entry in whole%val (rank 0), so a refactorization with the
      !> same pattern only moves values
      integer(ip), allocatable :: slots(:)
      integer(ip) :: local_nnz = -1
      logical :: analysed = .false.
      !> the whole matrix's diagonal is factorized times (1 + diagonal_shift) (`init`)
      real(dp) :: diagonal_shift = 0.0_dp
   contains
      procedure :: init
      procedure :: factor
      procedure :: solve
      procedure :: release_factor
   end type gathered_solver_t

contains

   !> The unknowns: key(i) of local unknown i, owned(i) if this rank owns it (each key is owned
   !> by exactly one rank), and the fill-reducing ordering and refinement steps of rank 0's
   !> factorization (twomem_linalg_umfpack; nested dissection and UMFPACK's default if absent).
   !> `diagonal_shift` (default 0): the factorized matrix is the whole one with its diagonal
   !> times 1 + diagonal_shift, for a caller whose matrix may be singular to round-off and
   !> who needs a bounded solve more than an exact one (multigrid's coarsest level).
   !> Collective.
   subroutine init(self, comm, key, owned, ordering, refinement_steps, diagonal_shift)
      class(gathered_solver_t), intent(out) :: self
      type(comm_t), intent(in) :: comm
      integer(ip), intent(in) :: key(:)
      logical, intent(in) :: owned(:)
      integer, intent(in), optional :: ordering, refinement_steps
      real(dp), intent(in), optional :: diagonal_shift

      integer(ip), allocatable :: mine(:)
      integer(ip) :: k

      if (present(ordering)) call self%direct%set_ordering(ordering)
      if (present(refinement_steps)) call self%direct%set_refinement(refinement_steps)
      if (present(diagonal_shift)) self%diagonal_shift = diagonal_shift
      self%comm = comm
      self%global = key
      self%owned = owned
      call comm%gather_counts(size(key), self%counts)
      allocate (self%all_global(merge(sum(self%counts), 0, comm%is_root())))
      call comm%gatherv(key, self%counts, self%all_global)
      mine = pack(key, owned)
      call comm%gather_counts(size(mine), self%owned_counts)
      allocate (self%all_owned_global(merge(sum(self%owned_counts), 0, comm%is_root())))
      call comm%gatherv(mine, self%owned_counts, self%all_owned_global)
      if (comm%is_root()) then
         self%keys = self%all_owned_global
         call sort_ints(self%keys)
         self%n_global = size(self%keys, kind=ip)
         do k = 1, size(self%all_global, kind=ip)
            self%all_global(k) = position(self%keys, self%all_global(k))
         end do
         do k = 1, size(self%all_owned_global, kind=ip)
            self%all_owned_global(k) = position(self%keys, self%all_owned_global(k))
         end do
      end if
   end subroutine init

   !> Position of `key` in the ascending array `keys` (binary search; the key is present).
   pure integer(ip) function position(keys, key) result(pos)
      integer(ip), intent(in) :: keys(:), key

      integer(ip) :: lo, hi

      lo = 1
      hi = size(keys, kind=ip)
      do while (lo < hi)
         pos = (lo + hi)/2
         if (keys(pos) < key) then
            lo = pos + 1
         else
            hi = pos
         end if
      end do
      pos = lo
   end function position


   !> Gather the parts `a` (local numbering, same pattern at every call after the first) and
   !> factorize the whole matrix on rank 0. Collective; every rank returns the same error.
   subroutine factor(self, a, err)
      class(gathered_solver_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      integer(ip), allocatable :: rows(:), cols(:), all_rows(:), all_cols(:)
      real(dp), allocatable :: all_vals(:)
      integer, allocatable :: counts(:)
      integer(ip) :: i, k

      if (self%local_nnz /= a%nnz()) self%analysed = .false.
      call self%comm%gather_counts(a%nnz(), counts)
      if (.not. self%analysed) then
         allocate (rows(a%nnz()), cols(a%nnz()))
         do i = 1, a%n
            do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
               rows(k) = self%global(i)
               cols(k) = self%global(a%col(k))
            end do
         end do
         allocate (all_rows(merge(sum(counts), 0, self%comm%is_root())), all_cols(merge(sum(counts), 0, &
                                                                                        self%comm%is_root())))
         call self%comm%gatherv(rows, counts, all_rows)
         call self%comm%gatherv(cols, counts, all_cols)
         if (self%comm%is_root()) then
            do k = 1, size(all_rows, kind=ip)
               all_rows(k) = position(self%keys, all_rows(k))
               all_cols(k) = position(self%keys, all_cols(k))
            end do
            call whole_pattern(self, all_rows, all_cols)
         end if
         self%local_nnz = a%nnz()
         self%analysed = .true.
      end if
      allocate (all_vals(merge(sum(counts), 0, self%comm%is_root())))
      call self%comm%gatherv(a%val(1:a%nnz()), counts, all_vals)
      if (self%comm%is_root()) then
         self%whole%val = 0.0_dp
         do k = 1, size(all_vals, kind=ip)
            self%whole%val(self%slots(k)) = self%whole%val(self%slots(k)) + all_vals(k)
         end do
         if (self%diagonal_shift > 0.0_dp) then
            do i = 1, self%whole%n
               k = self%whole%find(i, i)
               if (k > 0) self%whole%val(k) = self%whole%val(k)*(1 + self%diagonal_shift)
            end do
         end if
         call self%direct%factor(self%whole, err)
      end if
      call self%comm%agree(err)
   end subroutine factor

   !> rank 0: the pattern of the whole matrix from the gathered (row, column) pairs, and where
   !> each pair goes.
   subroutine whole_pattern(self, rows, cols)
      type(gathered_solver_t), intent(inout) :: self
      integer(ip), intent(in) :: rows(:), cols(:)

      integer(ip), allocatable :: row_ptr(:), col(:), fill(:)
      integer(ip) :: k, n, i

      n = self%n_global
      allocate (row_ptr(n + 1), fill(n))
      row_ptr = 0
      do k = 1, size(rows, kind=ip)
         row_ptr(rows(k) + 1) = row_ptr(rows(k) + 1) + 1
      end do
      row_ptr(1) = 1
      do i = 1, n
         row_ptr(i + 1) = row_ptr(i + 1) + row_ptr(i)
      end do
      ! every pair once per part: duplicates (shared entries) are merged after sorting
      allocate (col(size(rows)))
      fill = row_ptr(1:n)
      do k = 1, size(rows, kind=ip)
         col(fill(rows(k))) = cols(k)
         fill(rows(k)) = fill(rows(k)) + 1
      end do
      call self%whole%init_pattern(row_ptr, col)
      call merge_duplicates(self%whole)
      allocate (self%slots(size(rows)))
      do k = 1, size(rows, kind=ip)
         self%slots(k) = self%whole%find(rows(k), cols(k))
      end do
   end subroutine whole_pattern

   !> Drop repeated columns within each row of a sorted pattern.
   subroutine merge_duplicates(a)
      type(csr_t), intent(inout) :: a

      integer(ip), allocatable :: row_ptr(:), col(:)
      integer(ip) :: i, k, nnz

      allocate (row_ptr(a%n + 1), col(a%nnz()))
      nnz = 0
      row_ptr(1) = 1
      do i = 1, a%n
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (k > a%row_ptr(i)) then
               if (a%col(k) == a%col(k - 1)) cycle
            end if
            nnz = nnz + 1
            col(nnz) = a%col(k)
         end do
         row_ptr(i + 1) = nnz + 1
      end do
      call a%init_pattern(row_ptr, col(1:nnz))
   end subroutine merge_duplicates

   !> x = A⁻¹ b for the accumulated b (full values at every local unknown); x likewise.
   !> Collective.
   subroutine solve(self, b, x, err)
      class(gathered_solver_t), intent(inout) :: self
      real(dp), intent(in) :: b(:)
      real(dp), intent(out) :: x(:)
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: mine(:), owned_values(:), whole_b(:), whole_x(:), all_x(:)
      integer(ip) :: k

      mine = pack(b, self%owned)
      allocate (owned_values(merge(sum(self%owned_counts), 0, self%comm%is_root())))
      call self%comm%gatherv(mine, self%owned_counts, owned_values)
      allocate (all_x(merge(sum(self%counts), 0, self%comm%is_root())))
      if (self%comm%is_root()) then
         allocate (whole_b(self%n_global), whole_x(self%n_global))
         whole_b(self%all_owned_global) = owned_values
         call self%direct%solve(self%whole, whole_b, whole_x, err)
         if (.not. allocated(err)) then
            do k = 1, size(all_x, kind=ip)
               all_x(k) = whole_x(self%all_global(k))
            end do
         end if
      end if
      if (self%comm%size > 1) call self%comm%agree(err)
      if (allocated(err)) return
      call self%comm%scatterv_reals(all_x, self%counts, x)
   end subroutine solve

   !> The factorization and the whole matrix go, for a caller that solves no more; `factor`
   !> makes them again.
   subroutine release_factor(self)
      class(gathered_solver_t), intent(inout) :: self

      call self%direct%free()
      call self%whole%free()
      if (allocated(self%slots)) deallocate (self%slots)
      self%local_nnz = -1
      self%analysed = .false.
   end subroutine release_factor
end module twomem_linalg_gathered_solve
