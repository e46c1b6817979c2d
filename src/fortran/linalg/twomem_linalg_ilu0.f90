!> Incomplete LU factorization with zero fill, ILU(0), on a CSR matrix's own pattern: the
!> paper's preconditioner for GMRES on the full Newton matrix (docs/method.md §2). `setup` runs the
!> IKJ variant of Saad's ILU(0) (Iterative Methods for Sparse Linear Systems, 2nd ed., Alg. 10.4)
!> and stores L (unit lower, diagonal implied) and U in one value array on the matrix's pattern;
!> `apply` solves L U z = r by two triangular sweeps without allocating, since GMRES calls it
!> every iteration. Newton refactorizes every step with the same pattern, so the pattern-only
!> work (a copy of the pattern, diagonal positions, scratch) is kept and redone only when the
!> pattern changes. A missing diagonal or a tiny pivot is an `error_t` naming the row.
!>
!> Why the Newton matrix needs no reordering. In block order (X1, X2, X3) an active Newton-min
!> C-row of vertex i is [1, −1, 0] on columns (i, n+i, 2n+i); its λ-λ entry is an explicit zero
!> in the pattern. Rows i and n+i are eliminated first: row i of block 1 only meets block 3 in
!> column 2n+i (value −D_i) and row n+i of block 2 in the same column (value +D_i), and no
!> elimination step touches those entries (the fill they would create lies outside the
!> pattern). With s_i the ILU(0) pivot of S at row i (0 < s_i ≤ S_ii for the M-matrix S), the
!> U pivots of rows i and n+i are μ1 s_i and μ2 s_i, and eliminating the C-row gives
!>     l(2n+i, i) = 1/(μ1 s_i),  l(2n+i, n+i) = −1/(μ2 s_i),
!>     u(2n+i, 2n+i) = 0 − (1/(μ1 s_i))(−D_i) − (−1/(μ2 s_i))(D_i) = D_i (1/μ1 + 1/μ2)/s_i > 0.
!> An inactive row [0, 0, 1] keeps the pivot 1. For Fischer–Burmeister rows (da, −da, db) with
!> da, db ≤ 0 and not both zero the pivot is db + da D_i (1/μ1 + 1/μ2)/s_i < 0, again nonzero.
!> So the explicit zero on the diagonal is filled by elimination and block order works as is.
!>
!> Within a block, though, ILU(0) depends on the order of the unknowns, and the discrete
!> problem numbers them for the locality of its sparse products (twomem_fem_transfer), an order
!> that the paper's comparison should not depend on. `set_order` fixes the factorization's own
!> order by keys (the Newton solver gives the mesh's vertex order within each block, as the
!> direct solver's), and `setup` then factorizes the permuted matrix; `apply` permutes in and out.
module twomem_linalg_ilu0
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_not_converged
   use twomem_base_sort, only: sorting_permutation, sort_pairs
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: preconditioner_t
   implicit none
   private

   public :: ilu0_preconditioner_t

   !> A pivot |u_ii| ≤ pivot_rtol ‖a_i‖_∞ (the original row i) is a breakdown: dividing by it
   !> would give a preconditioner that amplifies round-off instead of approximating A⁻¹.
   real(dp), parameter :: pivot_rtol = 1.0e-14_dp

   type, extends(preconditioner_t) :: ilu0_preconditioner_t
      private
      integer(ip) :: n = 0
      !> true after a successful setup; apply acts as the identity otherwise
      logical :: ready = .false.
      !> true while row_ptr, col, diag describe a checked pattern (kept across setups)
      logical :: analysed = .false.
      !> number of pattern analyses so far (tests check that refactorization reuses them)
      integer :: analyses = 0
      integer(ip), allocatable :: row_ptr(:), col(:)
      !> position of (i, i) in col / lu
      integer(ip), allocatable :: diag(:)
      !> L strictly below the diagonal, U on and above it, on the pattern of A
      real(dp), allocatable :: lu(:)
      !> 1 / u_ii: the backward sweep multiplies instead of dividing (all in the factorization's
      !> order, which factor_entry's indices refer to)
      real(dp), allocatable :: inv_pivot(:)
      !> scratch for setup: position in the current row of each column, 0 if absent
      integer(ip), allocatable :: marker(:)
      !> with `set_order`: row k of the factorization is row order(k) of A, its entry m is A's
      !> entry value_map(m); work holds a permuted vector in apply
      logical :: ordered = .false.
      integer(ip), allocatable :: order(:), value_map(:)
      real(dp), allocatable :: work(:)
   contains
      procedure :: set_order
      procedure :: setup => ilu0_setup
      procedure :: apply => ilu0_apply
      procedure :: free => ilu0_free
      procedure :: factor_entry
      procedure :: n_analyses
   end type ilu0_preconditioner_t

contains

   !> Factorize the matrices of later setups in the order of ascending `keys` (one per row, all
   !> different) instead of their own.
   subroutine set_order(self, keys)
      class(ilu0_preconditioner_t), intent(inout) :: self
      integer(ip), intent(in) :: keys(:)

      call self%free()
      self%order = sorting_permutation(keys)
      self%ordered = .true.
   end subroutine set_order

   !> Factorize A ≈ L U on A's pattern (permuted, after `set_order`). The pattern data is kept
   !> when A's pattern equals the previous one (checked in O(nnz), cheap next to the
   !> factorization).
   subroutine ilu0_setup(self, a, err)
      class(ilu0_preconditioner_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      character(len=32) :: rows

      self%ready = .false.
      if (self%ordered) then
         ! (no short circuit in Fortran: the size is asked only of an order that is there)
         if (size(self%order, kind=ip) /= a%n) then
            write (rows, '(i0)') a%n
            call make_error(err, exit_not_converged, 'ilu0 setup', 'the order set has '// &
                            'another size than the matrix''s '//trim(rows)//' rows')
            return
         end if
      end if
      if (.not. same_pattern(self, a)) then
         call analyse(self, a, err)
         if (allocated(err)) return
      end if
      if (self%ordered) then
         self%lu(:) = a%val(self%value_map)
      else
         self%lu(:) = a%val(1:size(self%lu))
      end if
      call factorize(self%n, self%row_ptr, self%col, self%diag, self%lu, self%inv_pivot, &
                     self%marker, err)
      if (allocated(err)) return
      self%ready = .true.
   end subroutine ilu0_setup

   logical function same_pattern(self, a)
      type(ilu0_preconditioner_t), intent(in) :: self
      type(csr_t), intent(in) :: a

      integer(ip) :: nnz, k, m, i

      same_pattern = .false.
      if (.not. self%analysed) return
      if (a%n /= self%n) return
      nnz = a%row_ptr(a%n + 1) - 1
      if (nnz /= size(self%col)) return
      if (.not. self%ordered) then
         if (any(a%row_ptr(1:a%n + 1) /= self%row_ptr)) return
         if (any(a%col(1:nnz) /= self%col)) return
      else
         ! entry m of permuted row k must come from row order(k) of A, at column order(col(m))
         do k = 1, self%n
            i = self%order(k)
            if (a%row_ptr(i + 1) - a%row_ptr(i) /= self%row_ptr(k + 1) - self%row_ptr(k)) return
            do m = self%row_ptr(k), self%row_ptr(k + 1) - 1
               if (self%value_map(m) < a%row_ptr(i) .or. self%value_map(m) >= a%row_ptr(i + 1)) return
               if (a%col(self%value_map(m)) /= self%order(self%col(m))) return
            end do
         end do
      end if
      same_pattern = .true.
   end function same_pattern

   !> Copy the pattern, find the diagonal positions, size the value and scratch arrays.
   subroutine analyse(self, a, err)
      type(ilu0_preconditioner_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: i, nnz, m
      character(len=32) :: row

      call self%free()
      self%n = a%n
      nnz = a%row_ptr(a%n + 1) - 1
      if (self%ordered) then
         call permuted_pattern(a, self%order, self%row_ptr, self%col, self%value_map)
         allocate (self%work(self%n))
      else
         self%row_ptr = a%row_ptr(1:a%n + 1)
         self%col = a%col(1:nnz)
      end if
      allocate (self%diag(self%n), self%lu(nnz), self%inv_pivot(self%n), self%marker(self%n))
      self%marker = 0
      self%analyses = self%analyses + 1
      do i = 1, self%n
         ! (in the factorization's own pattern, which may be A's permuted)
         self%diag(i) = 0
         do m = self%row_ptr(i), self%row_ptr(i + 1) - 1
            if (self%col(m) == i) self%diag(i) = m
         end do
         if (self%diag(i) == 0) then
            write (row, '(i0)') i
            call make_error(err, exit_not_converged, 'ilu0 setup', &
                            'row '//trim(row)//' has no diagonal entry in the pattern '// &
                            '(ILU(0) needs every (i, i), an explicit zero if need be)')
            return
         end if
      end do
      self%analysed = .true.
   end subroutine analyse

   !> The pattern of P A Pᵀ, row k being row order(k) of A with column j at position(j), order's
   !> inverse, sorted; its entry m is A's entry value_map(m).
   subroutine permuted_pattern(a, order, row_ptr, col, value_map)
      type(csr_t), intent(in) :: a
      integer(ip), intent(in) :: order(:)
      integer(ip), allocatable, intent(out) :: row_ptr(:), col(:), value_map(:)

      integer(ip), allocatable :: position(:)
      integer(ip) :: k, i, j, m0, length

      allocate (position(a%n), row_ptr(a%n + 1), col(a%row_ptr(a%n + 1) - 1), value_map(a%row_ptr(a%n + 1) - 1))
      do k = 1, a%n
         position(order(k)) = k
      end do
      row_ptr(1) = 1
      do k = 1, a%n
         i = order(k)
         m0 = a%row_ptr(i)
         length = a%row_ptr(i + 1) - m0
         row_ptr(k + 1) = row_ptr(k) + length
         col(row_ptr(k):row_ptr(k + 1) - 1) = position(a%col(m0:m0 + length - 1))
         value_map(row_ptr(k):row_ptr(k + 1) - 1) = [(m0 + j - 1, j=1, length)]
         call sort_pairs(col(row_ptr(k):row_ptr(k + 1) - 1), value_map(row_ptr(k):row_ptr(k + 1) - 1))
      end do
   end subroutine permuted_pattern

   !> IKJ ILU(0) in place on lu (which holds A's values on entry). Row i is only changed while
   !> it is the current row, so its original values, hence its norm, are at hand when it
   !> starts. Each row needs the finished rows above it: this loop is sequential by nature
   !> (a level-scheduled or multicolour variant would be the way to thread it).
   subroutine factorize(n, row_ptr, col, diag, lu, inv_pivot, marker, err)
      integer(ip), intent(in) :: n
      integer(ip), intent(in) :: row_ptr(:), col(:), diag(:)
      real(dp), intent(inout) :: lu(:)
      real(dp), intent(out) :: inv_pivot(:)
      integer(ip), intent(inout) :: marker(:)
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: i, k, p, q, m
      real(dp) :: mult, row_norm, pivot
      character(len=120) :: msg

      do i = 1, n
         row_norm = 0.0_dp
         do p = row_ptr(i), row_ptr(i + 1) - 1
            marker(col(p)) = p
            row_norm = max(row_norm, abs(lu(p)))
         end do
         ! the L part in increasing column order: a multiplier is final once all columns to
         ! its left have been eliminated
         do p = row_ptr(i), diag(i) - 1
            k = col(p)
            mult = lu(p)*inv_pivot(k)
            lu(p) = mult
            ! explicit zeros (inactive C-rows) eliminate nothing
            if (mult == 0.0_dp) cycle
            do q = diag(k) + 1, row_ptr(k + 1) - 1
               m = marker(col(q))
               if (m /= 0) lu(m) = lu(m) - mult*lu(q)
            end do
         end do
         do p = row_ptr(i), row_ptr(i + 1) - 1
            marker(col(p)) = 0
         end do
         pivot = lu(diag(i))
         ! written so that a NaN pivot fails too
         if (.not. (abs(pivot) > pivot_rtol*row_norm)) then
            write (msg, '("zero or tiny pivot in row ",i0," (|u_ii| = ",es9.2, &
                 & ", max |a_ij| in the row = ",es9.2,")")') i, abs(pivot), row_norm
            call make_error(err, exit_not_converged, 'ilu0 setup', trim(msg))
            return
         end if
         inv_pivot(i) = 1.0_dp/pivot
      end do
   end subroutine factorize

   !> z = (L U)⁻¹ r: forward sweep with unit L, backward sweep with U, in place in z. Both
   !> sweeps are recurrences over the rows and stay serial (see factorize).
   subroutine ilu0_apply(self, r, z)
      class(ilu0_preconditioner_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      integer(ip) :: i

      if (.not. self%ready) then
         z = r
         return
      end if
      if (self%ordered) then
         ! z in the factorization's order, then back
         do i = 1, self%n
            z(i) = r(self%order(i))
         end do
         call solve_in_place(self, z)
         self%work = z
         do i = 1, self%n
            z(self%order(i)) = self%work(i)
         end do
      else
         z = r
         call solve_in_place(self, z)
      end if
   end subroutine ilu0_apply

   !> z = (L U)⁻¹ z in the factorization's order.
   subroutine solve_in_place(self, z)
      type(ilu0_preconditioner_t), intent(in) :: self
      real(dp), intent(inout) :: z(:)

      integer(ip) :: i, p
      real(dp) :: s

      associate (row_ptr => self%row_ptr, col => self%col, diag => self%diag, lu => self%lu, &
                 inv_pivot => self%inv_pivot)
         ! serial: z(i) needs z(1:i-1)
         do i = 1, self%n
            s = z(i)
            do p = row_ptr(i), diag(i) - 1
               s = s - lu(p)*z(col(p))
            end do
            z(i) = s
         end do
         ! serial: z(i) needs z(i+1:n)
         do i = self%n, 1, -1
            s = z(i)
            do p = diag(i) + 1, row_ptr(i + 1) - 1
               s = s - lu(p)*z(col(p))
            end do
            z(i) = s*inv_pivot(i)
         end do
      end associate
   end subroutine solve_in_place

   !> Forget factors and pattern; the analysis count (it describes the history) and the order of
   !> `set_order` (a setting) survive.
   subroutine ilu0_free(self)
      class(ilu0_preconditioner_t), intent(inout) :: self

      self%n = 0
      self%ready = .false.
      self%analysed = .false.
      if (allocated(self%row_ptr)) deallocate (self%row_ptr)
      if (allocated(self%col)) deallocate (self%col)
      if (allocated(self%diag)) deallocate (self%diag)
      if (allocated(self%lu)) deallocate (self%lu)
      if (allocated(self%inv_pivot)) deallocate (self%inv_pivot)
      if (allocated(self%marker)) deallocate (self%marker)
      if (allocated(self%value_map)) deallocate (self%value_map)
      if (allocated(self%work)) deallocate (self%work)
   end subroutine ilu0_free

   !> Entry (i, j) of the combined factor: l_ij below the diagonal, u_ij on and above it; 0 when
   !> (i, j) is not in the pattern or no factorization is held. For tests and diagnostics.
   pure real(dp) function factor_entry(self, i, j) result(v)
      class(ilu0_preconditioner_t), intent(in) :: self
      integer(ip), intent(in) :: i, j

      integer(ip) :: lo, hi, mid

      v = 0.0_dp
      if (.not. self%ready) return
      if (i < 1 .or. i > self%n) return
      lo = self%row_ptr(i)
      hi = self%row_ptr(i + 1) - 1
      do while (lo <= hi)
         mid = (lo + hi)/2
         if (self%col(mid) == j) then
            v = self%lu(mid)
            return
         else if (self%col(mid) < j) then
            lo = mid + 1
         else
            hi = mid - 1
         end if
      end do
   end function factor_entry

   !> How many times setup has analysed a new pattern.
   pure integer function n_analyses(self)
      class(ilu0_preconditioner_t), intent(in) :: self

      n_analyses = self%analyses
   end function n_analyses
end module twomem_linalg_ilu0
