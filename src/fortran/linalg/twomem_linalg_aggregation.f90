!> Algebraic coarse levels by smoothed aggregation (Vaněk, Mandel, Brezina, Computing 56, 1996):
!> the prolongations that extend a multigrid hierarchy below its coarsest mesh, so that a mesh
!> with no coarser meshes under it (a user's own fine mesh, or a large coarse mesh) still gets
!> V-cycles of O(n) work instead of a direct solve of the whole level. Unknowns strongly coupled
!> (|a_ij| ≥ θ (a_ii a_jj)^½) are grouped into aggregates of a node and its strong neighbours;
!> the tentative prolongation P₀ is the indicator of the aggregates, so it reproduces constants,
!> the near-kernel of the Laplacians multigrid serves here, and one damped Jacobi step
!> P = (I − ω D⁻¹A) P₀ with ω = 4/(3ρ), ρ ≥ λ_max(D⁻¹A) by Gershgorin's theorem, smooths its
!> columns into overlapping basis functions of low energy. The coarse operator Pᵀ A P is the
!> next level's matrix, and the construction repeats until a level is small enough for a
!> direct solve. The prolongations are plain sparse matrices: the multigrid uses them like the
!> geometric ones (Galerkin products, truncation at fixed unknowns, Chebyshev smoothing), except
!> that no coarse unknown sits at a fine one (`multigrid_transfer_t`'s nested levels have an
!> injection, these do not). Aggregation visits the unknowns in their order, which the discrete
!> problem chose for locality, so aggregates are compact and the result is deterministic.
!> Unknowns without a strong connection (identity rows, say) belong to no aggregate: their
!> prolongation rows are empty and the smoother alone treats them.
module twomem_linalg_aggregation
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_galerkin, only: galerkin_assemble
   implicit none
   private

   public :: aggregation_options_t, aggregation_levels, aggregate, smoothed_prolongation

   type :: aggregation_options_t
      !> θ of the strength of connection
      real(dp) :: strength = 0.08_dp
      !> a level with at most this many unknowns is the coarsest (solved directly)
      integer(ip) :: coarse_size = 2000
      !> the most algebraic levels below the given operator
      integer :: max_levels = 25
      !> coarsening that keeps more than this fraction of the unknowns has stalled: stop there
      real(dp) :: stall = 0.8_dp
   end type aggregation_options_t

contains

   !> The prolongations p(1..m) of the algebraic levels below the SPD operator `a`: p(l) from level
   !> l−1 to level l, level m being a's own (so p(m) has a%n rows), level 0 the coarsest. None
   !> when `a` is small enough already.
   subroutine aggregation_levels(a, options, p, err)
      type(csr_t), intent(in) :: a
      type(aggregation_options_t), intent(in) :: options
      type(csr_t), allocatable, intent(out) :: p(:)
      type(error_t), allocatable, intent(out) :: err

      type(csr_t), allocatable :: stack(:)
      type(csr_t) :: level, coarse
      integer(ip), allocatable :: agg(:)
      integer(ip) :: n_agg
      integer :: m, l

      allocate (stack(options%max_levels))
      m = 0
      level = a
      do while (level%n > options%coarse_size .and. m < options%max_levels)
         call aggregate(level, options%strength, agg, n_agg)
         if (n_agg == 0 .or. real(n_agg, dp) > options%stall*real(level%n, dp)) exit
         m = m + 1
         call smoothed_prolongation(level, agg, n_agg, stack(m))
         if (.not. all(level%diagonal() > 0.0_dp)) then
            call make_error(err, exit_io, 'multigrid', 'algebraic coarse levels need an operator with a positive '// &
                            'diagonal')
            return
         end if
         call galerkin_assemble(stack(m)%transposed(), level, stack(m), coarse)
         call level%free()
         call move_alloc(coarse%row_ptr, level%row_ptr)
         call move_alloc(coarse%col, level%col)
         call move_alloc(coarse%val, level%val)
         level%n = coarse%n
         level%ncol = coarse%ncol
      end do
      ! coarsest first: p(l) prolongs from level l−1
      allocate (p(m))
      do l = 1, m
         call move_alloc(stack(m + 1 - l)%row_ptr, p(l)%row_ptr)
         call move_alloc(stack(m + 1 - l)%col, p(l)%col)
         call move_alloc(stack(m + 1 - l)%val, p(l)%val)
         p(l)%n = stack(m + 1 - l)%n
         p(l)%ncol = stack(m + 1 - l)%ncol
      end do
   end subroutine aggregation_levels

   !> agg(i): the aggregate of unknown i (1..n_agg), 0 for an unknown without strong neighbours.
   !> Three passes: an unknown whose strong neighbours are all free founds an aggregate with them;
   !> an unknown left over joins the first-pass aggregate it is most strongly coupled to; what is
   !> still left (unknowns whose strong neighbours were all taken by later aggregates) founds an
   !> aggregate with its free strong neighbours.
   subroutine aggregate(a, theta, agg, n_agg)
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: theta
      integer(ip), allocatable, intent(out) :: agg(:)
      integer(ip), intent(out) :: n_agg

      real(dp), allocatable :: d(:)
      integer(ip), allocatable :: first(:)
      logical, allocatable :: has_strong(:)
      integer(ip) :: i, j, k, best
      real(dp) :: strongest, c
      logical :: free

      d = a%diagonal()
      allocate (agg(a%n), has_strong(a%n))
      agg = 0
      n_agg = 0
      do i = 1, a%n
         has_strong(i) = .false.
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (strong(i, k)) then
               has_strong(i) = .true.
               exit
            end if
         end do
      end do
      ! pass 1: aggregates of a root and all its strong neighbours
      do i = 1, a%n
         if (agg(i) /= 0 .or. .not. has_strong(i)) cycle
         free = .true.
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (strong(i, k)) free = free .and. agg(a%col(k)) == 0
         end do
         if (.not. free) cycle
         n_agg = n_agg + 1
         agg(i) = n_agg
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (strong(i, k)) agg(a%col(k)) = n_agg
         end do
      end do
      ! pass 2: the rest join the first-pass aggregate of their strongest neighbour
      first = agg
      do i = 1, a%n
         if (first(i) /= 0 .or. .not. has_strong(i)) cycle
         best = 0
         strongest = 0.0_dp
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            j = a%col(k)
            if (.not. strong(i, k) .or. first(j) == 0) cycle
            c = abs(a%val(k))/sqrt(d(i)*d(j))
            if (c > strongest) then
               strongest = c
               best = first(j)
            end if
         end do
         agg(i) = best
      end do
      ! pass 3: what no first-pass aggregate touches founds one with its free strong neighbours
      do i = 1, a%n
         if (agg(i) /= 0 .or. .not. has_strong(i)) cycle
         n_agg = n_agg + 1
         agg(i) = n_agg
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (strong(i, k)) then
               if (agg(a%col(k)) == 0) agg(a%col(k)) = n_agg
            end if
         end do
      end do

   contains

      !> Whether entry k of row i is a strong off-diagonal connection.
      logical function strong(i, k)
         integer(ip), intent(in) :: i, k

         integer(ip) :: j

         j = a%col(k)
         strong = .false.
         if (j == i .or. d(i) <= 0.0_dp .or. d(j) <= 0.0_dp) return
         strong = abs(a%val(k)) >= theta*sqrt(d(i)*d(j))
      end function strong
   end subroutine aggregate

   !> P = (I − ω D⁻¹A) P₀, P₀ the indicator matrix of the aggregates (n × n_agg), ω = 4/(3ρ) with
   !> ρ the Gershgorin bound of D⁻¹A. Row i couples to the aggregates of i and of its neighbours.
   subroutine smoothed_prolongation(a, agg, n_agg, p)
      type(csr_t), intent(in) :: a
      integer(ip), intent(in) :: agg(:), n_agg
      type(csr_t), intent(out) :: p

      real(dp), allocatable :: d(:)
      integer(ip), allocatable :: row_ptr(:), col(:), slot(:)
      integer(ip) :: i, k, j, c, length, pos
      real(dp) :: rho, omega

      d = a%diagonal()
      rho = 0.0_dp
      do i = 1, a%n
         if (d(i) > 0.0_dp) rho = max(rho, sum(abs(a%val(a%row_ptr(i):a%row_ptr(i + 1) - 1)))/d(i))
      end do
      omega = 0.0_dp
      if (rho > 0.0_dp) omega = 4.0_dp/(3.0_dp*rho)
      ! the pattern: the distinct aggregates of each row's unknowns
      allocate (row_ptr(a%n + 1), slot(n_agg))
      slot = 0
      row_ptr(1) = 1
      do i = 1, a%n
         length = 0
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            c = agg(a%col(k))
            if (c == 0) cycle
            if (slot(c) /= i) then
               slot(c) = i
               length = length + 1
            end if
         end do
         ! an unknown of no aggregate whose neighbours are in none either has an empty row
         row_ptr(i + 1) = row_ptr(i) + length
      end do
      allocate (col(row_ptr(a%n + 1) - 1))
      slot = 0
      do i = 1, a%n
         pos = row_ptr(i)
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            c = agg(a%col(k))
            if (c == 0) cycle
            if (slot(c) /= i) then
               slot(c) = i
               col(pos) = c
               pos = pos + 1
            end if
         end do
      end do
      call p%init_pattern(row_ptr, col, n_agg)
      do i = 1, a%n
         if (d(i) <= 0.0_dp) cycle
         if (agg(i) /= 0) then
            pos = p%find(i, agg(i))
            p%val(pos) = p%val(pos) + 1.0_dp
         end if
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            j = a%col(k)
            if (agg(j) == 0) cycle
            pos = p%find(i, agg(j))
            p%val(pos) = p%val(pos) - omega*a%val(k)/d(i)
         end do
      end do
   end subroutine smoothed_prolongation
end module twomem_linalg_aggregation
