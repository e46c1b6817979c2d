!> The abstractions iterative solvers are written against: a linear operator (y = A x), a
!> preconditioner (z ≈ A⁻¹ r, refreshed from a CSR matrix), and an inner product. GMRES sees
!> only these, so the same kernel runs serial, threaded or, later, distributed (an MPI inner
!> product and a halo-exchanging operator), and new preconditioners (multigrid) plug in
!> without touching it.
module twomem_linalg_operators
   use, intrinsic :: ieee_arithmetic, only: ieee_is_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_base_comm, only: comm_t
   use twomem_linalg_vectors, only: threaded_from
   implicit none
   private

   public :: linear_operator_t, preconditioner_t, inner_product_t
   public :: csr_operator_t, summed_csr_operator_t, identity_preconditioner_t, euclidean_product_t, distributed_product_t

   type, abstract :: linear_operator_t
   contains
      procedure(operator_apply), deferred :: apply
   end type linear_operator_t

   type, abstract :: preconditioner_t
   contains
      !> (re)build from the matrix; the pattern may be kept between calls with the same pattern
      procedure(preconditioner_setup), deferred :: setup
      !> z = M⁻¹ r; inout because a preconditioner may keep its work vectors (multigrid)
      procedure(preconditioner_apply), deferred :: apply
      !> give back the memory that the next setup or apply can rebuild, before a phase that
      !> needs the memory more than the preconditioner needs its time (the default keeps all)
      procedure :: release => keep_everything
   end type preconditioner_t

   type, abstract :: inner_product_t
   contains
      procedure(product_dot), deferred :: dot
      procedure :: norm
   end type inner_product_t

   abstract interface
      subroutine operator_apply(self, x, y)
         import :: linear_operator_t, dp
         class(linear_operator_t), intent(in) :: self
         real(dp), intent(in) :: x(:)
         real(dp), intent(out) :: y(:)
      end subroutine operator_apply

      subroutine preconditioner_setup(self, a, err)
         import :: preconditioner_t, csr_t, error_t
         class(preconditioner_t), intent(inout) :: self
         type(csr_t), intent(in) :: a
         type(error_t), allocatable, intent(out) :: err
      end subroutine preconditioner_setup

      subroutine preconditioner_apply(self, r, z)
         import :: preconditioner_t, dp
         class(preconditioner_t), intent(inout) :: self
         real(dp), intent(in) :: r(:)
         real(dp), intent(out) :: z(:)
      end subroutine preconditioner_apply

      real(dp) function product_dot(self, x, y)
         import :: inner_product_t, dp
         class(inner_product_t), intent(in) :: self
         real(dp), intent(in) :: x(:), y(:)
      end function product_dot
   end interface

   !> A CSR matrix as an operator. It points at the matrix, which the caller keeps alive and
   !> may refill between solves.
   type, extends(linear_operator_t) :: csr_operator_t
      type(csr_t), pointer :: a => null()
   contains
      procedure :: apply => csr_apply
   end type csr_operator_t

   !> y = A x with A each rank's part of a matrix assembled from its own triangles, the products
   !> summed over the ranks at shared unknowns (`halo`): the finest stiffness of a distributed run.
   type, extends(linear_operator_t) :: summed_csr_operator_t
      type(csr_t), pointer :: a => null()
      type(halo_t), pointer :: halo => null()
   contains
      procedure :: apply => summed_csr_apply
   end type summed_csr_operator_t

   !> No preconditioning (M = I).
   type, extends(preconditioner_t) :: identity_preconditioner_t
   contains
      procedure :: setup => identity_setup
      procedure :: apply => identity_apply
   end type identity_preconditioner_t

   !> The serial Euclidean product, threaded.
   type, extends(inner_product_t) :: euclidean_product_t
   contains
      procedure :: dot => euclidean_dot
   end type euclidean_product_t

   !> The Euclidean product of distributed vectors: every entry counted by the one rank that
   !> owns it (`owned` has the vectors' length), the ranks' sums added.
   type, extends(inner_product_t) :: distributed_product_t
      type(comm_t) :: comm
      logical, allocatable :: owned(:)
   contains
      procedure :: dot => distributed_dot
   end type distributed_product_t

contains

   !> sqrt(x·x); NaN stays NaN (max(0, NaN) may well be 0, which would call a NaN vector zero)
   real(dp) function norm(self, x)
      class(inner_product_t), intent(in) :: self
      real(dp), intent(in) :: x(:)

      real(dp) :: d

      d = self%dot(x, x)
      if (ieee_is_nan(d)) then
         norm = d
      else
         norm = sqrt(max(0.0_dp, d))
      end if
   end function norm

   subroutine csr_apply(self, x, y)
      class(csr_operator_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      call self%a%matvec(x, y)
   end subroutine csr_apply

   subroutine summed_csr_apply(self, x, y)
      class(summed_csr_operator_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      call self%a%matvec(x, y)
      call self%halo%add(y)
   end subroutine summed_csr_apply

   subroutine keep_everything(self)
      class(preconditioner_t), intent(inout) :: self
   end subroutine keep_everything

   subroutine identity_setup(self, a, err)
      class(identity_preconditioner_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err
   end subroutine identity_setup

   subroutine identity_apply(self, r, z)
      class(identity_preconditioner_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      z = r
   end subroutine identity_apply

   real(dp) function euclidean_dot(self, x, y) result(s)
      class(euclidean_product_t), intent(in) :: self
      real(dp), intent(in) :: x(:), y(:)

      s = blocked_dot(x, y)
   end function euclidean_dot

   !> As `euclidean_dot`, over the owned entries, then summed over the ranks.
   real(dp) function distributed_dot(self, x, y) result(s)
      class(distributed_product_t), intent(in) :: self
      real(dp), intent(in) :: x(:), y(:)

      s = self%comm%sum(blocked_dot(x, y, self%owned))
   end function distributed_dot

   !> xᵀy (over the entries where `owned` is true, when given) as sums of fixed-size blocks
   !> added in block order: the result is the same bits for any thread count (an OpenMP
   !> reduction adds the threads' sums in whatever order they finish, which would make GMRES
   !> iterates, and regression results, depend on the thread count).
   real(dp) function blocked_dot(x, y, owned) result(s)
      real(dp), intent(in) :: x(:), y(:)
      logical, intent(in), optional :: owned(:)

      !> fixes the order of the additions, so it is a constant of its own: whether threads
      !> share the blocks (threaded_from) changes no bit
      integer(ip), parameter :: block = 4096
      real(dp), allocatable :: partial(:)
      real(dp) :: acc
      integer(ip) :: n, nb, b, i
      logical :: masked

      n = size(x, kind=ip)
      nb = (n + block - 1)/block
      masked = present(owned)
      allocate (partial(nb))
      ! each block's sum in a private accumulator, stored once: accumulating in the shared array
      ! made the threads write neighbouring entries of one cache line at every element (false
      ! sharing, a visible share of the Newton solve's products: docs/performance.md)
      !$omp parallel do default(none) shared(x, y, owned, masked, partial, n, nb) private(b, i, acc) &
      !$omp schedule(static) if(n > threaded_from)
      do b = 1, nb
         acc = 0.0_dp
         if (masked) then
            do i = (b - 1)*block + 1, min(b*block, n)
               if (owned(i)) acc = acc + x(i)*y(i)
            end do
         else
            do i = (b - 1)*block + 1, min(b*block, n)
               acc = acc + x(i)*y(i)
            end do
         end if
         partial(b) = acc
      end do
      !$omp end parallel do
      s = sum(partial)
   end function blocked_dot
end module twomem_linalg_operators
