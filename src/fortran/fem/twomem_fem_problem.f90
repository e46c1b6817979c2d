!> Problem data as an extensible type: tensions, the Dirichlet value g of u1, the loads f1, f2
!> as functions of position and, when known, the exact solution. The assembly and the error
!> computation see only `problem_data_t`, so constant data, the built-in verification cases and
!> user data (formulas, nodal data: `twomem_fem_user_data`) are interchangeable.
module twomem_fem_problem
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: problem_data_t, constant_data_t

   type, abstract :: problem_data_t
      real(dp) :: mu1 = 1.0_dp, mu2 = 1.0_dp, g = 0.05_dp
      character(len=16) :: name = ''
   contains
      procedure(load_interface), deferred :: load
      procedure :: loads_at
      procedure :: constant_loads
      procedure :: has_exact
      procedure :: exact
      procedure :: exact_gradients_at
      procedure :: explain_load
   end type problem_data_t

   abstract interface
      !> f_alpha(x), alpha = 1 or 2
      pure real(dp) function load_interface(self, alpha, x)
         import :: problem_data_t, dp
         class(problem_data_t), intent(in) :: self
         integer, intent(in) :: alpha
         real(dp), intent(in) :: x(2)
      end function load_interface
   end interface

   !> Constant loads, no known solution.
   type, extends(problem_data_t) :: constant_data_t
      real(dp) :: f1 = -0.25_dp, f2 = 0.25_dp
   contains
      procedure :: load => constant_load
      procedure :: loads_at => constant_loads_at
      !> (an extension that overrides `load` must override this too)
      procedure :: constant_loads => constant_loads_values
   end type constant_data_t

contains

   !> f(α, k) = f_α(x(:, k)) for a batch of points: one dynamic dispatch per batch instead of
   !> two per point (assembly evaluates 14 values per triangle).
   pure subroutine loads_at(self, x, f)
      class(problem_data_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: f(:, :)

      integer :: k

      do k = 1, size(x, 2)
         f(1, k) = self%load(1, x(:, k))
         f(2, k) = self%load(2, x(:, k))
      end do
   end subroutine loads_at

   !> constant = .true. with f = [f1, f2] when both loads are constant on Ω, so that their
   !> integrals against fixed functions need no quadrature per element; .false. by default.
   pure subroutine constant_loads(self, f, constant)
      class(problem_data_t), intent(in) :: self
      real(dp), intent(out) :: f(2)
      logical, intent(out) :: constant

      f = 0.0_dp
      constant = .false.
   end subroutine constant_loads

   pure subroutine constant_loads_values(self, f, constant)
      class(constant_data_t), intent(in) :: self
      real(dp), intent(out) :: f(2)
      logical, intent(out) :: constant

      f = [self%f1, self%f2]
      constant = .true.
   end subroutine constant_loads_values

   pure subroutine constant_loads_at(self, x, f)
      class(constant_data_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: f(:, :)

      f(1, :) = self%f1
      f(2, :) = self%f2
   end subroutine constant_loads_at

   !> Why f_alpha is not finite at x, for the error message ('' when there is nothing to add).
   function explain_load(self, alpha, x) result(why)
      class(problem_data_t), intent(in) :: self
      integer, intent(in) :: alpha
      real(dp), intent(in) :: x(2)
      character(len=:), allocatable :: why

      why = ''
   end function explain_load

   pure logical function has_exact(self)
      class(problem_data_t), intent(in) :: self

      has_exact = .false.
   end function has_exact

   !> Exact u1, u2, λ and the gradients of u1, u2 at x. Only called when `has_exact`.
   pure subroutine exact(self, x, u, grad)
      class(problem_data_t), intent(in) :: self
      real(dp), intent(in) :: x(2)
      !> u1, u2, lambda
      real(dp), intent(out) :: u(3)
      !> grad(:, alpha) = ∇u_alpha
      real(dp), intent(out) :: grad(2, 2)

      u = [self%g, 0.0_dp, 0.0_dp]
      grad = 0.0_dp
   end subroutine exact

   !> grad(:, α, k) = ∇u_α at x(:, k), the exact gradients alone for a batch of points: the
   !> energy error needs nothing else, at 16 and 7 points per triangle, and a case whose values
   !> cost more than its gradients (a logarithm, a square root) overrides this to skip them.
   pure subroutine exact_gradients_at(self, x, grad)
      class(problem_data_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: grad(:, :, :)

      real(dp) :: u(3)
      integer :: k

      do k = 1, size(x, 2)
         call self%exact(x(:, k), u, grad(:, :, k))
      end do
   end subroutine exact_gradients_at

   pure real(dp) function constant_load(self, alpha, x)
      class(constant_data_t), intent(in) :: self
      integer, intent(in) :: alpha
      real(dp), intent(in) :: x(2)

      constant_load = merge(self%f1, self%f2, alpha == 1)
   end function constant_load
end module twomem_fem_problem
