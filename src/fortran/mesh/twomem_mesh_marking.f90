!> Dörfler's bulk marking (SIAM J. Numer. Anal. 33, 1996), the MARK of adaptive refinement: the
!> fewest triangles whose squared indicators carry the fraction θ of their sum, which is what
!> makes estimator-driven refinement converge at the optimal rate (Stevenson 2007; Cascon,
!> Kreuzer, Nochetto, Siebert 2008). The set is {K : η_K² ≥ τ} for the largest threshold τ
!> that still collects θ Σ η_K², found by bisection on τ: O(N) per halving and independent of
!> the order of the triangles, so every rank that holds the same indicators marks the same set.
module twomem_mesh_marking
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: dorfler_marking

contains

   !> marked(K): η_K² ≥ τ with τ the largest threshold (to round-off) for which the marked
   !> squares sum to at least θ Σ η_K². All indicators zero: nothing is marked.
   function dorfler_marking(eta, theta) result(marked)
      real(dp), intent(in) :: eta(:)
      real(dp), intent(in) :: theta
      logical, allocatable :: marked(:)

      real(dp), allocatable :: squares(:)
      real(dp) :: lo, hi, mid, target
      integer :: it

      squares = eta**2
      target = theta*sum(squares)
      allocate (marked(size(eta)))
      if (target <= 0.0_dp) then
         marked = .false.
         return
      end if
      ! invariant: threshold lo collects enough, hi does not (nothing is strictly above the
      ! maximum); the halvings end when the interval is below the squares' resolution
      lo = 0.0_dp
      hi = maxval(squares)*(1 + 4*epsilon(1.0_dp))
      do it = 1, 200
         mid = 0.5_dp*(lo + hi)
         if (mid <= lo .or. mid >= hi) exit
         if (sum(squares, mask=squares >= mid) >= target) then
            lo = mid
         else
            hi = mid
         end if
      end do
      ! lo < max: the largest indicator is always marked
      marked = squares >= lo .and. squares > 0.0_dp
   end function dorfler_marking
end module twomem_mesh_marking
