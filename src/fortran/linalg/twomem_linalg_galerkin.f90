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
!> result does not depend on the thread count.
module twomem_linalg_galerkin
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   implicit none
   private

   public :: galerkin_pattern, galerkin_values, truncate_transfer

contains

   !> The pattern of Pᵀ A P (untruncated, so it serves every fixed set), values zero. r = Pᵀ.
   subroutine galerkin_pattern(r, a, p, c)
      type(csr_t), intent(in) :: r, a, p
      type(csr_t), intent(inout) :: c

      integer(ip), allocatable :: counts(:), row_ptr(:), col(:), marker(:)
      integer(ip) :: nc, i, k, m, q, j, l, fill

      nc = r%n
      allocate (counts(nc))
      ! two passes over the same loops: count the distinct columns of each row, then list them
      !$omp parallel default(none) shared(r, a, p, nc, counts, row_ptr, col) &
      !$omp private(marker, i, k, m, q, j, l, fill)
      allocate (marker(nc))
      marker = 0
      !$omp do schedule(static)
      do i = 1, nc
         fill = 0
         do k = r%row_ptr(i), r%row_ptr(i + 1) - 1
            do m = a%row_ptr(r%col(k)), a%row_ptr(r%col(k) + 1) - 1
               j = a%col(m)
               do q = p%row_ptr(j), p%row_ptr(j + 1) - 1
                  l = p%col(q)
                  if (marker(l) /= i) then
                     marker(l) = i
                     fill = fill + 1
                  end if
               end do
            end do
         end do
         ! the diagonal is always stored: a coarse row cut off entirely becomes an identity row
         if (marker(i) /= i) fill = fill + 1
         counts(i) = fill
      end do
      !$omp end do
      !$omp single
      allocate (row_ptr(nc + 1))
      row_ptr(1) = 1
      do i = 1, nc
         row_ptr(i + 1) = row_ptr(i) + counts(i)
      end do
      allocate (col(row_ptr(nc + 1) - 1))
      !$omp end single
      marker = 0
      !$omp do schedule(static)
      do i = 1, nc
         fill = row_ptr(i)
         do k = r%row_ptr(i), r%row_ptr(i + 1) - 1
            do m = a%row_ptr(r%col(k)), a%row_ptr(r%col(k) + 1) - 1
               j = a%col(m)
               do q = p%row_ptr(j), p%row_ptr(j + 1) - 1
                  l = p%col(q)
                  if (marker(l) /= i) then
                     marker(l) = i
                     col(fill) = l
                     fill = fill + 1
                  end if
               end do
            end do
         end do
         if (marker(i) /= i) col(fill) = i
      end do
      !$omp end do
      deallocate (marker)
      !$omp end parallel
      call c%init_pattern(row_ptr, col)
   end subroutine galerkin_pattern

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
   !> level's.
   subroutine galerkin_values(r, rv, a, p, pv, coarse_fixed, halo, c)
      type(csr_t), intent(in) :: r, a, p
      real(dp), intent(in) :: rv(:), pv(:)
      logical, intent(in) :: coarse_fixed(:)
      type(halo_t), intent(inout) :: halo
      type(csr_t), intent(inout) :: c

      real(dp), allocatable :: diag(:)
      integer(ip), allocatable :: d(:)
      integer(ip) :: i

      call product_rows(c%n, r%row_ptr, r%col, rv, a%row_ptr, a%col, a%val, p%row_ptr, p%col, pv, &
                        c%row_ptr, c%col, c%val)
      allocate (diag(c%n), d(c%n))
      do i = 1, c%n
         d(i) = c%find(i, i)
         diag(i) = c%val(d(i))
      end do
      call halo%add(diag)
      !$omp parallel do default(none) shared(c, coarse_fixed, diag, d, halo) private(i) schedule(static) &
      !$omp if(c%n > 4096)
      do i = 1, c%n
         if (coarse_fixed(i) .or. .not. diag(i) > 0.0_dp) then
            ! a fixed or cut-off unknown: an identity row, decoupled from the others
            c%val(c%row_ptr(i):c%row_ptr(i + 1) - 1) = 0.0_dp
            c%val(d(i)) = merge(1.0_dp, 0.0_dp, halo%owned(i))
         end if
      end do
      !$omp end parallel do
   end subroutine galerkin_values

   !> The numeric product on plain arrays (contiguous dummies let the compiler keep every base
   !> address in a register in the innermost loop).
   subroutine product_rows(nc, r_ptr, r_col, rv, a_ptr, a_col, a_val, p_ptr, p_col, pv, c_ptr, c_col, c_val)
      integer(ip), intent(in) :: nc
      integer(ip), intent(in) :: r_ptr(:), r_col(:), a_ptr(:), a_col(:), p_ptr(:), p_col(:), c_ptr(:), c_col(:)
      real(dp), intent(in) :: rv(:), a_val(:), pv(:)
      real(dp), intent(inout) :: c_val(:)

      integer(ip), allocatable :: position(:)
      integer(ip) :: i, k, m, q, kk, j
      real(dp) :: rik, rikakj

      !$omp parallel default(none) shared(nc, r_ptr, r_col, rv, a_ptr, a_col, a_val, p_ptr, p_col, pv) &
      !$omp shared(c_ptr, c_col, c_val) private(position, i, k, m, q, kk, j, rik, rikakj) if(nc > 1024)
      allocate (position(nc))
      !$omp do schedule(static)
      do i = 1, nc
         do m = c_ptr(i), c_ptr(i + 1) - 1
            c_val(m) = 0.0_dp
            position(c_col(m)) = m
         end do
         do k = r_ptr(i), r_ptr(i + 1) - 1
            rik = rv(k)
            if (rik == 0.0_dp) cycle
            kk = r_col(k)
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
