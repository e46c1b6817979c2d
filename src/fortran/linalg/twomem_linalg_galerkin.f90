!> Galerkin coarse operators A_c = Pᵀ A P of multigrid, with truncation: rows and columns of
!> fixed unknowns (Dirichlet rows of the fine operator, contact rows of the Newton system) are
!> cut out of the prolongation, P_t(i, j) = P(i, j) only where fine i and coarse j are both
!> free, so the coarse space never moves a fixed unknown. Like a direct solver the work splits
!> into a symbolic phase (the pattern of A_c, once per pattern of A and P) and a numeric phase
!> (the values, whenever A or the fixed set change: every Newton step for the contact block).
!> Truncation is applied to the transfer values once (`truncate_transfer`), so the products
!> themselves run without branches. In a distributed run each rank multiplies its own parts
!> (Σ_p P_pᵀ A_p P_p = Pᵀ A P), so no matrix rows travel; only the diagonal is summed across
!> ranks to find the rows that truncation emptied. Both phases run row-parallel over the coarse rows, each row
!> gathered from Pᵀ (held as its own CSR, `r`), so no two threads write the same entry and the
!> result does not depend on the thread count. The numeric phase also runs on a list of rows
!> (`galerkin_rows`): a row is computed by the same operations whatever else is listed, so a
!> multigrid that recomputes only the rows a change can reach (`touched_rows`) holds the bits of
!> a full product; `cut_rows` then redoes the identity rows of the listed rows.
module twomem_linalg_galerkin
   use twomem_base_kinds, only: dp, ip
   use twomem_base_sort, only: sort_pairs
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_vectors, only: copy_allocated, threaded_from
   implicit none
   private

   public :: galerkin_pattern, galerkin_assemble, galerkin_values, truncate_transfer, galerkin_rows, &
             galerkin_diagonal_rows, cut_rows, touched_rows

contains

   !> The pattern of Pᵀ A P (untruncated, so it serves every fixed set), values zero. r = Pᵀ.
   subroutine galerkin_pattern(r, a, p, c)
      type(csr_t), intent(in) :: r, a, p
      type(csr_t), intent(inout) :: c

      call pattern_and_values(r, a, p, .false., c)
   end subroutine galerkin_pattern

   !> The pattern of Pᵀ A P and its values with the untruncated transfer, in one pass: for a
   !> hierarchy built once with nothing fixed (the S-block), half the work of pattern, then
   !> values. The values have the bits of `galerkin_rows` with R's and P's own values.
   subroutine galerkin_assemble(r, a, p, c)
      type(csr_t), intent(in) :: r, a, p
      type(csr_t), intent(inout) :: c

      call pattern_and_values(r, a, p, .true., c)
   end subroutine galerkin_assemble

   !> One pass over the triple loops: each thread lists the columns (and, `with_values`, the
   !> values, summed in the order of `product_rows`) of its rows in buffers of its own, and the
   !> buffers are joined in row order (a static schedule gives every thread one contiguous
   !> block of rows, in order), so the result does not depend on the thread count.
   subroutine pattern_and_values(r, a, p, with_values, c)
      type(csr_t), intent(in) :: r, a, p
      logical, intent(in) :: with_values
      type(csr_t), intent(inout) :: c

      integer(ip), allocatable :: counts(:), row_ptr(:), col(:), slot(:), buffer(:)
      real(dp), allocatable :: val(:), values(:)
      integer(ip) :: nc, i, k, m, q, j, l, used, first, start
      real(dp) :: rik, rikakj

      nc = r%n
      allocate (counts(nc), row_ptr(nc + 1))
      !$omp parallel default(none) shared(r, a, p, nc, counts, row_ptr, col, val, with_values) &
      !$omp private(slot, buffer, values, used, first, start, i, k, m, q, j, l, rik, rikakj)
      ! slot(l): where column l of the current row sits in the buffer (stale if before `start`)
      allocate (slot(nc), buffer(1024), values(1024))
      slot = 0
      used = 0
      first = 0
      !$omp do schedule(static)
      do i = 1, nc
         if (first == 0) first = i
         start = used + 1
         do k = r%row_ptr(i), r%row_ptr(i + 1) - 1
            rik = r%val(k)
            do m = a%row_ptr(r%col(k)), a%row_ptr(r%col(k) + 1) - 1
               rikakj = rik*a%val(m)
               j = a%col(m)
               do q = p%row_ptr(j), p%row_ptr(j + 1) - 1
                  l = p%col(q)
                  if (slot(l) < start) then
                     call append(buffer, values, used, l)
                     slot(l) = used
                  end if
                  if (with_values .and. rik /= 0.0_dp) values(slot(l)) = values(slot(l)) + rikakj*p%val(q)
               end do
            end do
         end do
         ! the diagonal is always stored: a coarse row cut off entirely becomes an identity row
         if (slot(i) < start) call append(buffer, values, used, i)
         counts(i) = used - start + 1
      end do
      !$omp end do
      !$omp single
      row_ptr(1) = 1
      do i = 1, nc
         row_ptr(i + 1) = row_ptr(i) + counts(i)
      end do
      allocate (col(row_ptr(nc + 1) - 1), val(row_ptr(nc + 1) - 1))
      !$omp end single
      if (first > 0) then
         col(row_ptr(first):row_ptr(first) + used - 1) = buffer(1:used)
         val(row_ptr(first):row_ptr(first) + used - 1) = values(1:used)
      end if
      deallocate (slot, buffer, values)
      !$omp end parallel
      ! columns sorted within each row, the values moved along
      !$omp parallel do default(none) shared(nc, row_ptr, col, val) private(i) schedule(static) if(nc > threaded_from)
      do i = 1, nc
         call sort_pairs(col(row_ptr(i):row_ptr(i + 1) - 1), val(row_ptr(i):row_ptr(i + 1) - 1))
      end do
      !$omp end parallel do
      call c%init_pattern(row_ptr, col)
      if (with_values) c%val = val
   end subroutine pattern_and_values

   !> buffer(used + 1) = value and values(used + 1) = 0, doubling both when full.
   pure subroutine append(buffer, values, used, value)
      integer(ip), allocatable, intent(inout) :: buffer(:)
      real(dp), allocatable, intent(inout) :: values(:)
      integer(ip), intent(inout) :: used
      integer(ip), intent(in) :: value

      integer(ip), allocatable :: larger(:)
      real(dp), allocatable :: more(:)

      if (used == size(buffer)) then
         allocate (larger(2*size(buffer)), more(2*size(buffer)))
         larger(1:used) = buffer
         more(1:used) = values
         call move_alloc(larger, buffer)
         call move_alloc(more, values)
      end if
      used = used + 1
      buffer(used) = value
      values(used) = 0.0_dp
   end subroutine append

   !> The values of P and R = Pᵀ truncated at fixed unknowns: zero where the fine or the coarse
   !> unknown of an entry is fixed.
   subroutine truncate_transfer(p, r, fine_fixed, coarse_fixed, pt, rt)
      type(csr_t), intent(in) :: p, r
      logical, intent(in) :: fine_fixed(:), coarse_fixed(:)
      real(dp), intent(out) :: pt(:), rt(:)

      integer(ip) :: i, k

      !$omp parallel default(none) shared(p, r, fine_fixed, coarse_fixed, pt, rt) private(i, k)
      !$omp do schedule(static)
      do i = 1, p%n
         do k = p%row_ptr(i), p%row_ptr(i + 1) - 1
            pt(k) = merge(0.0_dp, p%val(k), fine_fixed(i) .or. coarse_fixed(p%col(k)))
         end do
      end do
      !$omp end do nowait
      !$omp do schedule(static)
      do i = 1, r%n
         do k = r%row_ptr(i), r%row_ptr(i + 1) - 1
            rt(k) = merge(0.0_dp, r%val(k), coarse_fixed(i) .or. fine_fixed(r%col(k)))
         end do
      end do
      !$omp end do
      !$omp end parallel
   end subroutine truncate_transfer

   !> c%val = values of Rv A Pv on the pattern of `galerkin_pattern`, where rv and pv are the
   !> (possibly truncated) values of R and P on their patterns. Rows of fixed coarse unknowns,
   !> and rows that truncation left empty, become identity rows (the owner of a shared row
   !> holds the 1, so the ranks' parts add up to it). `a` must have identity rows (and zero
   !> columns) at its fixed unknowns, which truncated values never reach. `halo` is the coarse
   !> level's. Collective.
   subroutine galerkin_values(r, rv, a, p, pv, coarse_fixed, halo, c)
      type(csr_t), intent(in) :: r, a, p
      real(dp), intent(in) :: rv(:), pv(:)
      logical, intent(in) :: coarse_fixed(:)
      type(halo_t), intent(inout) :: halo
      type(csr_t), intent(inout) :: c

      real(dp), allocatable :: part_diag(:)
      logical, allocatable :: cut(:), updated(:)
      integer(ip), allocatable :: rows(:), regain(:)
      integer(ip) :: i

      rows = [(i, i=1, c%n)]
      call galerkin_rows(r, rv, a, p, pv, rows, c%row_ptr, c%col, c%val)
      allocate (part_diag(c%n), cut(c%n), updated(c%n))
      cut = .false.
      updated = .true.
      call cut_rows(rows, coarse_fixed, halo, part_diag, cut, c, updated, regain)
   end subroutine galerkin_values

   !> The rows `rows` of Rv A Pv into c_val (on the coarse pattern c_ptr, c_col of
   !> `galerkin_pattern`), other rows left alone; with `start` (values on the same pattern) the
   !> product is added to start's values of those rows.
   subroutine galerkin_rows(r, rv, a, p, pv, rows, c_ptr, c_col, c_val, start)
      type(csr_t), intent(in) :: r, a, p
      real(dp), intent(in) :: rv(:), pv(:)
      integer(ip), intent(in) :: rows(:), c_ptr(:), c_col(:)
      real(dp), intent(inout) :: c_val(:)
      real(dp), intent(in), optional :: start(:)

      real(dp) :: zero(0)
      logical :: no_mask(0)

      if (present(start)) then
         call product_rows(r%n, rows, r%row_ptr, r%col, rv, a%row_ptr, a%col, a%val, p%row_ptr, p%col, pv, &
                           c_ptr, c_col, c_val, .true., start, .false., no_mask, no_mask)
      else
         call product_rows(r%n, rows, r%row_ptr, r%col, rv, a%row_ptr, a%col, a%val, p%row_ptr, p%col, pv, &
                           c_ptr, c_col, c_val, .false., zero, .false., no_mask, no_mask)
      end if
   end subroutine galerkin_rows

   !> galerkin_rows with start for A = diag(d) on the owned free unknowns, 0 on the others (a
   !> fixed unknown's row is an identity row; in a distributed run the owner's part of a shared
   !> row alone holds its diagonal): the operations of a product with that diagonal stored as a
   !> matrix, so the same bits, without storing it (16 bytes per fine unknown).
   subroutine galerkin_diagonal_rows(r, rv, d, owned, fixed, p, pv, rows, c_ptr, c_col, c_val, start)
      type(csr_t), intent(in) :: r, p
      real(dp), intent(in) :: rv(:), d(:), pv(:), start(:)
      logical, intent(in) :: owned(:), fixed(:)
      integer(ip), intent(in) :: rows(:), c_ptr(:), c_col(:)
      real(dp), intent(inout) :: c_val(:)

      integer(ip) :: no_pattern(0)

      call product_rows(r%n, rows, r%row_ptr, r%col, rv, no_pattern, no_pattern, d, p%row_ptr, p%col, pv, &
                        c_ptr, c_col, c_val, .true., start, .true., owned, fixed)
   end subroutine galerkin_diagonal_rows

   !> After the rows `rows` of c were recomputed: the identity rows. part_diag keeps this rank's
   !> part of each row's diagonal as computed (an identity row loses it), cut the identity rows
   !> of the last call; both are updated. A row becomes an identity row when its coarse unknown
   !> is fixed or the diagonal summed over the ranks is not positive (truncation emptied it).
   !> In a distributed run that sum can change while this rank's part of the row did not: such
   !> rows are marked in `updated` too, and those that stop being identity rows are returned in
   !> `regain` for the caller to recompute (their values were overwritten). Collective.
   subroutine cut_rows(rows, coarse_fixed, halo, part_diag, cut, c, updated, regain)
      integer(ip), intent(in) :: rows(:)
      logical, intent(in) :: coarse_fixed(:)
      type(halo_t), intent(inout) :: halo
      real(dp), intent(inout) :: part_diag(:)
      logical, intent(inout) :: cut(:), updated(:)
      type(csr_t), intent(inout) :: c
      integer(ip), allocatable, intent(out) :: regain(:)

      real(dp), allocatable :: diag(:)
      logical, allocatable :: listed(:), lost(:)
      integer(ip) :: i, j
      logical :: now_cut

      allocate (listed(c%n), lost(c%n))
      listed = .false.
      !$omp parallel do default(none) shared(rows, c, part_diag, listed) private(j) schedule(static) &
      !$omp if(size(rows) > threaded_from)
      do j = 1, size(rows, kind=ip)
         part_diag(rows(j)) = c%val(c%find(rows(j), rows(j)))
         listed(rows(j)) = .true.
      end do
      !$omp end parallel do
      diag = part_diag
      call halo%add(diag)
      !$omp parallel do default(none) shared(c, coarse_fixed, diag, halo, cut, listed, updated, lost) &
      !$omp private(i, now_cut) schedule(static) if(c%n > threaded_from)
      do i = 1, c%n
         now_cut = coarse_fixed(i) .or. .not. diag(i) > 0.0_dp
         lost(i) = .false.
         if (now_cut .and. (listed(i) .or. .not. cut(i))) then
            ! a fixed or cut-off unknown: an identity row, decoupled from the others
            c%val(c%row_ptr(i):c%row_ptr(i + 1) - 1) = 0.0_dp
            c%val(c%find(i, i)) = merge(1.0_dp, 0.0_dp, halo%owned(i))
         else if (.not. now_cut .and. cut(i) .and. .not. listed(i)) then
            lost(i) = .true.
         end if
         updated(i) = updated(i) .or. (now_cut .neqv. cut(i))
         cut(i) = now_cut
      end do
      !$omp end parallel do
      regain = pack([(i, i=1, c%n)], lost)
   end subroutine cut_rows

   !> The coarse rows of Rt A Pt that a change can reach: the fine rows of A whose values changed
   !> (`changed`; A is symmetric, so their columns changed too) and the fine unknowns whose fixed
   !> flag flipped (`flipped`: the truncated R and P change around them), and the coarse
   !> unknowns whose fixed flag flipped (`coarse_flipped`: their truncated rows of R change).
   !> Dilating the fine marks through A, P and R costs a few passes over their patterns, far less
   !> than the products it saves; when the marks are few (a Newton step near convergence), they
   !> are spread from the marked entries instead, at a cost that shrinks with the change.
   subroutine touched_rows(r, a, p, coarse_flipped, flipped, changed, touched)
      type(csr_t), intent(in) :: r, a, p
      logical, intent(in) :: coarse_flipped(:), flipped(:), changed(:)
      logical, intent(out) :: touched(:)

      logical, allocatable :: moved(:), reach(:)
      integer(ip) :: i, k, n_flipped, n_changed

      n_flipped = count(flipped)
      n_changed = count(changed)
      if (n_flipped == 0 .and. n_changed == 0) then
         touched = .false.
         return
      else if (n_flipped == 0 .and. n_changed == size(changed)) then
         touched = .true.
         return
      end if
      ! scattering costs a few dozen operations per mark, gathering ten per entry of A
      if (4*(n_flipped + n_changed) < a%n) then
         call spread_marks(r, a, p, flipped, changed, coarse_flipped, touched)
         return
      end if
      allocate (moved(p%n), reach(a%n))
      !$omp parallel default(none) shared(r, a, p, flipped, changed, touched, coarse_flipped, moved, reach) &
      !$omp private(i, k)
      ! moved: rows of the truncated P that changed
      !$omp do schedule(static)
      do i = 1, p%n
         moved(i) = flipped(i)
         do k = p%row_ptr(i), p%row_ptr(i + 1) - 1
            moved(i) = moved(i) .or. coarse_flipped(p%col(k))
         end do
      end do
      !$omp end do
      ! reach: rows of A Pt that changed
      !$omp do schedule(static)
      do i = 1, a%n
         reach(i) = flipped(i) .or. changed(i)
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (reach(i)) exit
            reach(i) = changed(a%col(k)) .or. moved(a%col(k))
         end do
      end do
      !$omp end do
      !$omp do schedule(static)
      do i = 1, r%n
         touched(i) = coarse_flipped(i)
         do k = r%row_ptr(i), r%row_ptr(i + 1) - 1
            if (touched(i)) exit
            touched(i) = reach(r%col(k))
         end do
      end do
      !$omp end do
      !$omp end parallel
   end subroutine touched_rows

   !> touched_rows for few marks, by scattering from them (A's pattern is symmetric, R is Pᵀ).
   subroutine spread_marks(r, a, p, flipped, changed, coarse_flipped, touched)
      type(csr_t), intent(in) :: r, a, p
      logical, intent(in) :: flipped(:), changed(:), coarse_flipped(:)
      logical, intent(out) :: touched(:)

      logical, allocatable :: moved(:), reach(:)
      integer(ip) :: i, k

      ! (the full-length copies threaded: their first touch is most of this routine's time)
      call copy_allocated(flipped, moved)
      do i = 1, r%n
         if (coarse_flipped(i)) moved(r%col(r%row_ptr(i):r%row_ptr(i + 1) - 1)) = .true.
      end do
      allocate (reach(a%n))
      !$omp parallel do default(none) shared(a, reach, flipped, changed) private(i) &
      !$omp schedule(static) if(a%n > threaded_from)
      do i = 1, a%n
         reach(i) = flipped(i) .or. changed(i)
      end do
      !$omp end parallel do
      do i = 1, a%n
         if (changed(i) .or. moved(i)) reach(a%col(a%row_ptr(i):a%row_ptr(i + 1) - 1)) = .true.
      end do
      !$omp parallel do default(none) shared(touched, coarse_flipped) private(i) schedule(static) &
      !$omp if(size(touched) > threaded_from)
      do i = 1, size(touched, kind=ip)
         touched(i) = coarse_flipped(i)
      end do
      !$omp end parallel do
      do i = 1, p%n
         if (reach(i)) then
            do k = p%row_ptr(i), p%row_ptr(i + 1) - 1
               touched(p%col(k)) = .true.
            end do
         end if
      end do
   end subroutine spread_marks

   !> The numeric product on plain arrays (contiguous dummies let the compiler keep every base
   !> address in a register in the innermost loop), on the listed rows, each from 0 or, with
   !> `from_start`, from the values in `start`. With `diagonal`, A = diag(a_val) read as 0 where
   !> an unknown is not `owned` or is `fixed` (a_ptr and a_col are then not read): the
   !> operations of that diagonal stored as a matrix.
   subroutine product_rows(nc, rows, r_ptr, r_col, rv, a_ptr, a_col, a_val, p_ptr, p_col, pv, c_ptr, c_col, c_val, &
                           from_start, start, diagonal, owned, fixed)
      integer(ip), intent(in) :: nc
      integer(ip), intent(in) :: rows(:), r_ptr(:), r_col(:), a_ptr(:), a_col(:), p_ptr(:), p_col(:), c_ptr(:), &
                                 c_col(:)
      real(dp), intent(in) :: rv(:), a_val(:), pv(:)
      real(dp), intent(inout) :: c_val(:)
      logical, intent(in) :: from_start
      real(dp), intent(in) :: start(:)
      logical, intent(in) :: diagonal
      logical, intent(in) :: owned(:), fixed(:)

      integer(ip), allocatable :: position(:)
      integer(ip) :: i, k, m, q, kk, j, jr
      real(dp) :: rik, rikakj

      !$omp parallel default(none) shared(nc, rows, r_ptr, r_col, rv, a_ptr, a_col, a_val, p_ptr, p_col, pv) &
      !$omp shared(c_ptr, c_col, c_val, start, from_start, diagonal, owned, fixed) &
      !$omp private(position, i, k, m, q, kk, j, jr, rik, rikakj) if(size(rows) > threaded_from)
      allocate (position(nc))
      !$omp do schedule(static)
      do jr = 1, size(rows, kind=ip)
         i = rows(jr)
         do m = c_ptr(i), c_ptr(i + 1) - 1
            position(c_col(m)) = m
         end do
         if (from_start) then
            c_val(c_ptr(i):c_ptr(i + 1) - 1) = start(c_ptr(i):c_ptr(i + 1) - 1)
         else
            c_val(c_ptr(i):c_ptr(i + 1) - 1) = 0.0_dp
         end if
         do k = r_ptr(i), r_ptr(i + 1) - 1
            rik = rv(k)
            if (rik == 0.0_dp) cycle
            kk = r_col(k)
            if (diagonal) then
               rikakj = rik*merge(a_val(kk), 0.0_dp, owned(kk) .and. .not. fixed(kk))
               do q = p_ptr(kk), p_ptr(kk + 1) - 1
                  c_val(position(p_col(q))) = c_val(position(p_col(q))) + rikakj*pv(q)
               end do
               cycle
            end if
            do m = a_ptr(kk), a_ptr(kk + 1) - 1
               rikakj = rik*a_val(m)
               j = a_col(m)
               do q = p_ptr(j), p_ptr(j + 1) - 1
                  c_val(position(p_col(q))) = c_val(position(p_col(q))) + rikakj*pv(q)
               end do
            end do
         end do
      end do
      !$omp end do
      deallocate (position)
      !$omp end parallel
   end subroutine product_rows
end module twomem_linalg_galerkin
