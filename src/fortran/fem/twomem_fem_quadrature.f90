!> Quadrature rules on triangles in barycentric form, weights summing to one (multiply by the
!> area). Degree 5 (7 points, Dunavant) is the workhorse: loads with a jump inside an element
!> and the pointwise parts λ⁺, λ⁻ of the estimators need at least degree 4 and 7 points.
!> Degree 8 (16 points) measures the exact error where a kink crosses elements.
module twomem_fem_quadrature
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: quadrature_t, triangle_rule

   type :: quadrature_t
      integer :: n = 0
      integer :: degree = 0
      !> barycentric coordinates (3, n) and weights (n), sum(weights) = 1
      real(dp), allocatable :: bary(:, :), weights(:)
   contains
      procedure :: points
   end type quadrature_t

contains

   !> The cheapest stored rule that integrates polynomials of `degree` exactly (up to 8).
   function triangle_rule(degree) result(rule)
      integer, intent(in) :: degree
      type(quadrature_t) :: rule

      real(dp), parameter :: none(0) = [real(dp) ::]

      if (degree <= 1) then
         call set_rule(rule, 1, 1.0_dp, none, none, none, none, none)
      else if (degree <= 5) then
         call set_rule(rule, 5, 0.225_dp, &
                       [0.470142064105115_dp, 0.101286507323456_dp], &
                       [0.132394152788506_dp, 0.125939180544827_dp], none, none, none)
      else
         call set_rule(rule, 8, 0.144315607677787_dp, &
                       [0.459292588292723_dp, 0.170569307751760_dp, 0.050547228317031_dp], &
                       [0.095091634267285_dp, 0.103217370534718_dp, 0.032458497623198_dp], &
                       [0.263112829634638_dp], [0.008394777409958_dp], [0.027230314174435_dp])
      end if
   end function triangle_rule

   !> Assemble a symmetric rule from its orbits: the centroid, points (a, a, 1-2a) and their
   !> 3 permutations, points (a, b, 1-a-b) and their 6 permutations.
   subroutine set_rule(rule, degree, w_centre, three_a, three_w, six_a, six_b, six_w)
      type(quadrature_t), intent(inout) :: rule
      integer, intent(in) :: degree
      real(dp), intent(in) :: w_centre, three_a(:), three_w(:), six_a(:), six_b(:), six_w(:)

      integer :: i, k
      real(dp) :: a, b, c

      rule%n = 1 + 3*size(three_a) + 6*size(six_a)
      rule%degree = degree
      allocate (rule%bary(3, rule%n), rule%weights(rule%n))
      rule%bary(:, 1) = 1.0_dp/3
      rule%weights(1) = w_centre
      k = 1
      do i = 1, size(three_a)
         a = three_a(i)
         rule%bary(:, k + 1) = [a, a, 1 - 2*a]
         rule%bary(:, k + 2) = [a, 1 - 2*a, a]
         rule%bary(:, k + 3) = [1 - 2*a, a, a]
         rule%weights(k + 1:k + 3) = three_w(i)
         k = k + 3
      end do
      do i = 1, size(six_a)
         a = six_a(i)
         b = six_b(i)
         c = 1 - a - b
         rule%bary(:, k + 1) = [a, b, c]
         rule%bary(:, k + 2) = [a, c, b]
         rule%bary(:, k + 3) = [b, a, c]
         rule%bary(:, k + 4) = [b, c, a]
         rule%bary(:, k + 5) = [c, a, b]
         rule%bary(:, k + 6) = [c, b, a]
         rule%weights(k + 1:k + 6) = six_w(i)
         k = k + 6
      end do
   end subroutine set_rule

   !> Physical quadrature points of the triangle with corners p(:,1:3), (2, n).
   pure function points(self, p) result(x)
      class(quadrature_t), intent(in) :: self
      real(dp), intent(in) :: p(2, 3)
      real(dp) :: x(2, self%n)

      x = matmul(p, self%bary)
   end function points
end module twomem_fem_quadrature
