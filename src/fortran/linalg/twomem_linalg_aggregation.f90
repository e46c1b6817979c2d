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
!> Distributed, each rank aggregates the unknowns it owns, with the parts of the operator it
!> holds (the diagonal summed across ranks), so aggregates never straddle ranks and no rows
!> travel. The aggregates are numbered across the ranks in rank order; a rank learns the
!> aggregate of each shared unknown it does not own from the owner (one interface sum). Rows of
!> shared unknowns keep the tentative prolongation, so that every rank holding a shared unknown
!> computes the same row; rows of a rank's other unknowns, whose operator rows are whole on it,
!> are smoothed. A rank's coarse unknowns are its own aggregates and the others' aggregates its
!> rows reach; each owner learns who reaches its aggregates, and tells them who else does, which
!> gives every coarse level its interface (`halo_t`), possibly between ranks that share no fine
!> unknown. The coarsest level is gathered and solved directly, as a coarsest mesh is.
module twomem_linalg_aggregation
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_comm, only: comm_t
   use twomem_base_sort, only: sort_ints, sorting_permutation
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_galerkin, only: galerkin_assemble
   implicit none
   private

   public :: aggregation_options_t, aggregation_levels, aggregate

   type :: aggregation_options_t
      !> θ of the strength of connection
      real(dp) :: strength = 0.08_dp
      !> a level with at most this many unknowns (over all ranks) is the coarsest, solved directly
      integer(ip) :: coarse_size = 2000
      !> the most algebraic levels below the given operator
      integer :: max_levels = 25
      !> coarsening that keeps more than this fraction of the unknowns has stalled: stop there
      real(dp) :: stall = 0.8_dp
   end type aggregation_options_t

   !> One coarse level as this rank holds it: the prolongation from it, its interface, and the
   !> global key of each of its unknowns.
   type :: coarse_level_t
      type(csr_t) :: p
      type(halo_t) :: halo
      integer(ip), allocatable :: keys(:)
   end type coarse_level_t

contains

   !> The algebraic levels below the SPD operator `a` (this rank's part; `halo` the interface of
   !> its unknowns): prolongations p(1..m), p(l) from level l−1 to level l, level m being a's own
   !> (p(m) has a%n rows) and level 0 the coarsest; halos(0:m−1) the interfaces of the coarse
   !> levels, and `keys` the global keys of level 0's unknowns (for its gathered solve). None
   !> when `a` is small enough already. Collective.
   subroutine aggregation_levels(a, halo, options, p, halos, keys, err)
      type(csr_t), intent(in) :: a
      type(halo_t), intent(in) :: halo
      type(aggregation_options_t), intent(in) :: options
      type(csr_t), allocatable, intent(out) :: p(:)
      type(halo_t), allocatable, intent(out) :: halos(:)
      integer(ip), allocatable, intent(out) :: keys(:)
      type(error_t), allocatable, intent(out) :: err

      type(coarse_level_t), allocatable :: made(:)
      type(csr_t) :: level, coarse
      type(halo_t) :: level_halo
      integer :: m, l
      integer :: n_global, n_coarse_global
      logical :: bad_diagonal

      allocate (made(options%max_levels))
      m = 0
      call level%copy_from(a)
      level_halo = halo
      n_global = level_halo%comm%sum(int(level_halo%n_owned()))
      do while (n_global > options%coarse_size .and. m < options%max_levels)
         bad_diagonal = .not. all(summed_diagonal(level, level_halo) > 0.0_dp)
         if (level_halo%comm%any_true(bad_diagonal)) then
            call make_error(err, exit_io, 'multigrid', 'algebraic coarse levels need an operator with a positive '// &
                            'diagonal')
            return
         end if
         call coarsen_level(level, level_halo, options%strength, made(m + 1), err)
         if (allocated(err)) return
         n_coarse_global = level_halo%comm%sum(int(made(m + 1)%halo%n_owned()))
         if (n_coarse_global == 0 .or. real(n_coarse_global, dp) > options%stall*real(n_global, dp)) exit
         m = m + 1
         call galerkin_assemble(made(m)%p%transposed(), level, made(m)%p, coarse)
         call level%copy_from(coarse)
         call coarse%free()
         level_halo = made(m)%halo
         n_global = n_coarse_global
      end do
      ! coarsest first: p(l) prolongs from level l−1
      allocate (p(m), halos(0:m - 1))
      do l = 1, m
         call p(l)%copy_from(made(m + 1 - l)%p)
         halos(l - 1) = made(m + 1 - l)%halo
      end do
      if (m > 0) keys = made(m)%keys
   end subroutine aggregation_levels

   !> The diagonal of a distributed operator (its parts summed over the ranks).
   function summed_diagonal(a, halo) result(d)
      type(csr_t), intent(in) :: a
      type(halo_t), intent(inout) :: halo
      real(dp), allocatable :: d(:)

      d = a%diagonal()
      call halo%add(d)
   end function summed_diagonal

   !> One coarse level below `a`: aggregates of the unknowns this rank owns, the prolongation,
   !> the coarse interface and keys. Collective.
   subroutine coarsen_level(a, halo, theta, coarse, err)
      type(csr_t), intent(in) :: a
      type(halo_t), intent(inout) :: halo
      real(dp), intent(in) :: theta
      type(coarse_level_t), intent(out) :: coarse
      type(error_t), allocatable, intent(out) :: err

      type(comm_t) :: comm
      real(dp), allocatable :: d(:), key_values(:)
      integer(ip), allocatable :: agg(:), key_of(:), foreign(:), offsets(:)
      integer, allocatable :: counts(:)
      logical, allocatable :: shared(:)
      integer(ip) :: n_agg, i
      real(dp) :: rho

      comm = halo%comm
      d = summed_diagonal(a, halo)
      call aggregate(a, theta, agg, n_agg, eligible=halo%owned, diagonal=d)
      ! the aggregates numbered across the ranks in rank order
      allocate (counts(0:comm%size - 1))
      counts = 0
      counts(comm%rank) = int(n_agg)
      call comm%sum_in_place(counts)
      allocate (offsets(0:comm%size))
      offsets(0) = 0
      do i = 1, comm%size
         offsets(i) = offsets(i - 1) + counts(i - 1)
      end do
      ! every local unknown's aggregate key: the owner's, through one interface sum
      allocate (key_values(a%n))
      do i = 1, a%n
         key_values(i) = 0.0_dp
         if (halo%owned(i) .and. agg(i) > 0) key_values(i) = real(offsets(comm%rank) + agg(i), dp)
      end do
      call halo%add(key_values)
      key_of = nint(key_values, ip)
      allocate (shared(a%n))
      shared = .false.
      shared(halo%shared) = .true.
      rho = comm%max(gershgorin(a, d))
      call coarse_columns(a, key_of, shared, offsets(comm%rank), n_agg, foreign)
      call smoothed_prolongation(a, d, key_of, shared, 4.0_dp/(3.0_dp*rho), offsets(comm%rank), n_agg, foreign, coarse%p)
      coarse%keys = [(offsets(comm%rank) + i, i=1, n_agg), foreign]
      call coarse_halo(halo, offsets, n_agg, foreign, coarse%keys, coarse%halo, err)
   end subroutine coarsen_level

   !> max_i Σ_j |a_ij| / a_ii over this rank's rows (with the summed diagonal d): an upper
   !> bound of λ_max(D⁻¹A) on the rows whole here, which are the ones smoothed.
   real(dp) function gershgorin(a, d) result(rho)
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: d(:)

      integer(ip) :: i

      rho = 0.0_dp
      do i = 1, a%n
         if (d(i) > 0.0_dp) rho = max(rho, sum(abs(a%val(a%row_ptr(i):a%row_ptr(i + 1) - 1)))/d(i))
      end do
   end function gershgorin

   !> agg(i): the aggregate of unknown i (1..n_agg), 0 for an unknown that is not `eligible` (not
   !> this rank's) or has no strong eligible neighbour. Three passes: an unknown whose strong
   !> neighbours are all free founds an aggregate with them; an unknown left over joins the
   !> first-pass aggregate it is most strongly coupled to; what is still left (unknowns whose
   !> strong neighbours were all taken by later aggregates) founds one with its free strong
   !> neighbours. `diagonal` (default: a's) is the whole diagonal of a distributed operator.
   subroutine aggregate(a, theta, agg, n_agg, eligible, diagonal)
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: theta
      integer(ip), allocatable, intent(out) :: agg(:)
      integer(ip), intent(out) :: n_agg
      logical, intent(in), optional :: eligible(:)
      real(dp), intent(in), optional :: diagonal(:)

      real(dp), allocatable :: d(:)
      integer(ip), allocatable :: first(:)
      logical, allocatable :: has_strong(:), mine(:)
      integer(ip) :: i, j, k, best
      real(dp) :: strongest, c
      logical :: free

      if (present(diagonal)) then
         d = diagonal
      else
         d = a%diagonal()
      end if
      allocate (mine(a%n))
      mine = .true.
      if (present(eligible)) mine = eligible
      allocate (agg(a%n), has_strong(a%n))
      agg = 0
      n_agg = 0
      do i = 1, a%n
         has_strong(i) = .false.
         if (.not. mine(i)) cycle
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

      !> Whether entry k of row i is a strong off-diagonal connection between eligible unknowns.
      logical function strong(i, k)
         integer(ip), intent(in) :: i, k

         integer(ip) :: j

         j = a%col(k)
         strong = .false.
         if (j == i .or. .not. mine(j) .or. d(i) <= 0.0_dp .or. d(j) <= 0.0_dp) return
         strong = abs(a%val(k)) >= theta*sqrt(d(i)*d(j))
      end function strong
   end subroutine aggregate

   !> The other ranks' aggregates that this rank's prolongation rows reach (sorted keys): the
   !> aggregate of every shared unknown, and of every neighbour of an unshared unknown.
   subroutine coarse_columns(a, key_of, shared, offset, n_agg, foreign)
      type(csr_t), intent(in) :: a
      integer(ip), intent(in) :: key_of(:), offset, n_agg
      logical, intent(in) :: shared(:)
      integer(ip), allocatable, intent(out) :: foreign(:)

      integer(ip), allocatable :: list(:)
      integer(ip) :: i, k, n

      allocate (list(a%nnz() + a%n))
      n = 0
      do i = 1, a%n
         if (shared(i)) then
            call note(key_of(i))
         else
            do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
               call note(key_of(a%col(k)))
            end do
         end if
      end do
      call sort_ints(list(1:n))
      ! unique
      k = 0
      do i = 1, n
         if (k > 0) then
            if (list(k) == list(i)) cycle
         end if
         k = k + 1
         list(k) = list(i)
      end do
      foreign = list(1:k)

   contains

      subroutine note(key)
         integer(ip), intent(in) :: key

         if (key == 0 .or. (key > offset .and. key <= offset + n_agg)) return
         n = n + 1
         list(n) = key
      end subroutine note
   end subroutine coarse_columns

   !> The local coarse number of global aggregate key: own aggregates first, then `foreign`.
   pure integer(ip) function local_column(key, offset, n_agg, foreign) result(c)
      integer(ip), intent(in) :: key, offset, n_agg, foreign(:)

      integer(ip) :: lo, hi, mid

      if (key > offset .and. key <= offset + n_agg) then
         c = key - offset
         return
      end if
      lo = 1
      hi = size(foreign, kind=ip)
      c = 0
      do while (lo <= hi)
         mid = (lo + hi)/2
         if (foreign(mid) == key) then
            c = n_agg + mid
            return
         else if (foreign(mid) < key) then
            lo = mid + 1
         else
            hi = mid - 1
         end if
      end do
   end function local_column

   !> P = (I − ω D⁻¹A) P₀ on the unshared rows, P₀ on the shared ones (the same row on every rank
   !> that holds the unknown), P₀ the indicator of the aggregates (key_of), columns numbered
   !> by `local_column`.
   subroutine smoothed_prolongation(a, d, key_of, shared, omega, offset, n_agg, foreign, p)
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: d(:), omega
      integer(ip), intent(in) :: key_of(:), offset, n_agg, foreign(:)
      logical, intent(in) :: shared(:)
      type(csr_t), intent(out) :: p

      integer(ip), allocatable :: row_ptr(:), col(:), slot(:)
      integer(ip) :: i, k, c, length, pos, n_coarse

      n_coarse = n_agg + size(foreign, kind=ip)
      allocate (row_ptr(a%n + 1), slot(n_coarse))
      slot = 0
      row_ptr(1) = 1
      do i = 1, a%n
         length = 0
         if (shared(i)) then
            if (key_of(i) /= 0) length = 1
         else
            do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
               if (key_of(a%col(k)) == 0) cycle
               c = local_column(key_of(a%col(k)), offset, n_agg, foreign)
               if (slot(c) /= i) then
                  slot(c) = i
                  length = length + 1
               end if
            end do
         end if
         row_ptr(i + 1) = row_ptr(i) + length
      end do
      allocate (col(row_ptr(a%n + 1) - 1))
      slot = 0
      do i = 1, a%n
         pos = row_ptr(i)
         if (shared(i)) then
            if (key_of(i) /= 0) col(pos) = local_column(key_of(i), offset, n_agg, foreign)
            cycle
         end if
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (key_of(a%col(k)) == 0) cycle
            c = local_column(key_of(a%col(k)), offset, n_agg, foreign)
            if (slot(c) /= i) then
               slot(c) = i
               col(pos) = c
               pos = pos + 1
            end if
         end do
      end do
      call p%init_pattern(row_ptr, col, n_coarse)
      do i = 1, a%n
         if (key_of(i) /= 0) then
            pos = p%find(i, local_column(key_of(i), offset, n_agg, foreign))
            p%val(pos) = p%val(pos) + 1.0_dp
         end if
         if (shared(i) .or. d(i) <= 0.0_dp) cycle
         do k = a%row_ptr(i), a%row_ptr(i + 1) - 1
            if (key_of(a%col(k)) == 0) cycle
            pos = p%find(i, local_column(key_of(a%col(k)), offset, n_agg, foreign))
            p%val(pos) = p%val(pos) - omega*a%val(k)/d(i)
         end do
      end do
   end subroutine smoothed_prolongation

   !> The interface of the coarse level: own aggregates (owned here) and `foreign` ones (owned by
   !> the rank whose key range holds them). Each rank tells the owners which of their aggregates
   !> it reaches; each owner answers, per aggregate, with every rank that reaches it. Both
   !> messages go to fine neighbours (a foreign aggregate holds a shared unknown). Collective.
   subroutine coarse_halo(fine, offsets, n_agg, foreign, keys, halo, err)
      type(halo_t), intent(inout) :: fine
      integer(ip), intent(in) :: offsets(0:), n_agg, foreign(:), keys(:)
      type(halo_t), intent(out) :: halo
      type(error_t), allocatable, intent(out) :: err

      type(comm_t) :: comm
      integer, allocatable :: owner_of_foreign(:), send_ptr(:), recv_ptr(:), owner(:), neighbours(:), ptr(:)
      integer, allocatable :: reach_ptr(:), reach_rank(:)
      real(dp), allocatable :: send(:), recv(:)
      integer(ip), allocatable :: idx(:), order(:)
      logical, allocatable :: with(:, :)
      integer(ip) :: j, c, n_coarse
      integer :: k, q, nb, pos, r, n_share, m

      comm = fine%comm
      nb = size(fine%neighbours)
      n_coarse = n_agg + size(foreign, kind=ip)
      allocate (owner_of_foreign(size(foreign)))
      do j = 1, size(foreign, kind=ip)
         owner_of_foreign(j) = owner_rank(foreign(j))
         if (.not. any(fine%neighbours == owner_of_foreign(j))) then
            call make_error(err, exit_io, 'multigrid', 'an aggregate reached across ranks that share no unknown')
            return
         end if
      end do
      ! 1. to each neighbour: the keys of its aggregates reached here (foreign is sorted, and
      !    owners' key ranges ascend with the rank, so each neighbour's keys are consecutive)
      allocate (send_ptr(nb + 1))
      send_ptr(1) = 1
      do k = 1, nb
         send_ptr(k + 1) = send_ptr(k) + count(owner_of_foreign == fine%neighbours(k))
      end do
      send = real(pack(foreign, owner_of_foreign /= comm%rank), dp)
      call exchange_lists(comm, fine%neighbours, send, send_ptr, recv, recv_ptr)
      ! the ranks reaching each own aggregate, as lists reach_rank(reach_ptr(c):reach_ptr(c+1)−1)
      allocate (reach_ptr(n_agg + 1))
      reach_ptr = 0
      do pos = 1, size(recv)
         c = nint(recv(pos), ip) - offsets(comm%rank)
         reach_ptr(c + 1) = reach_ptr(c + 1) + 1
      end do
      reach_ptr(1) = 1
      do c = 1, n_agg
         reach_ptr(c + 1) = reach_ptr(c + 1) + reach_ptr(c)
      end do
      allocate (reach_rank(reach_ptr(n_agg + 1) - 1))
      block
         integer, allocatable :: fill(:)

         fill = reach_ptr(1:n_agg)
         do k = 1, nb
            do pos = recv_ptr(k), recv_ptr(k + 1) - 1
               c = nint(recv(pos), ip) - offsets(comm%rank)
               reach_rank(fill(c)) = fine%neighbours(k)
               fill(c) = fill(c) + 1
            end do
         end do
      end block
      ! 2. to each neighbour, per key it sent: how many ranks reach that aggregate, then which
      send_ptr(1) = 1
      do k = 1, nb
         n_share = 0
         do pos = recv_ptr(k), recv_ptr(k + 1) - 1
            c = nint(recv(pos), ip) - offsets(comm%rank)
            n_share = n_share + 1 + (reach_ptr(c + 1) - reach_ptr(c))
         end do
         send_ptr(k + 1) = send_ptr(k) + n_share
      end do
      deallocate (send)
      allocate (send(send_ptr(nb + 1) - 1))
      m = 0
      do k = 1, nb
         do pos = recv_ptr(k), recv_ptr(k + 1) - 1
            c = nint(recv(pos), ip) - offsets(comm%rank)
            m = m + 1
            send(m) = real(reach_ptr(c + 1) - reach_ptr(c), dp)
            do r = reach_ptr(c), reach_ptr(c + 1) - 1
               m = m + 1
               send(m) = real(reach_rank(r), dp)
            end do
         end do
      end do
      call exchange_lists(comm, fine%neighbours, send, send_ptr, recv, recv_ptr)
      ! every coarse unknown's sharers: for an own aggregate the ranks reaching it; for a foreign
      ! one its owner and the other ranks reaching it
      allocate (with(n_coarse, 0:comm%size - 1))
      with = .false.
      do c = 1, n_agg
         do r = reach_ptr(c), reach_ptr(c + 1) - 1
            with(c, reach_rank(r)) = .true.
         end do
      end do
      do k = 1, nb
         pos = recv_ptr(k)
         do j = 1, size(foreign, kind=ip)
            if (owner_of_foreign(j) /= fine%neighbours(k)) cycle
            with(n_agg + j, owner_of_foreign(j)) = .true.
            n_share = nint(recv(pos))
            do r = 1, n_share
               q = nint(recv(pos + r))
               if (q /= comm%rank) with(n_agg + j, q) = .true.
            end do
            pos = pos + 1 + n_share
         end do
      end do
      ! the halo: neighbours in ascending order, each one's shared unknowns in key order
      neighbours = pack([(q, q=0, comm%size - 1)], any(with, dim=1))
      allocate (ptr(size(neighbours) + 1))
      ptr(1) = 1
      do k = 1, size(neighbours)
         ptr(k + 1) = ptr(k) + count(with(:, neighbours(k)))
      end do
      order = sorting_permutation(keys)
      allocate (idx(ptr(size(neighbours) + 1) - 1))
      do k = 1, size(neighbours)
         pos = ptr(k)
         do j = 1, n_coarse
            if (with(order(j), neighbours(k))) then
               idx(pos) = order(j)
               pos = pos + 1
            end if
         end do
      end do
      allocate (owner(n_coarse))
      owner(1:n_agg) = comm%rank
      owner(n_agg + 1:) = owner_of_foreign
      call halo%init(comm, owner, neighbours, ptr, idx)

   contains

      !> The rank whose aggregate key range holds `key`.
      integer function owner_rank(key)
         integer(ip), intent(in) :: key

         do owner_rank = 0, comm%size - 1
            if (key > offsets(owner_rank) .and. key <= offsets(owner_rank + 1)) return
         end do
         owner_rank = -1
      end function owner_rank
   end subroutine coarse_halo

   !> Lists of any length to the neighbour ranks: their lengths first, then the lists. recv and
   !> recv_ptr are made here. Collective among the neighbours.
   subroutine exchange_lists(comm, neighbours, send, send_ptr, recv, recv_ptr)
      type(comm_t), intent(in) :: comm
      integer, intent(in) :: neighbours(:)
      real(dp), intent(in) :: send(:)
      integer, intent(in) :: send_ptr(:)
      real(dp), allocatable, intent(out) :: recv(:)
      integer, allocatable, intent(out) :: recv_ptr(:)

      real(dp), allocatable :: lengths_out(:), lengths_in(:)
      integer, allocatable :: one(:)
      integer :: k, nb

      nb = size(neighbours)
      one = [(k, k=1, nb + 1)]
      lengths_out = [(real(send_ptr(k + 1) - send_ptr(k), dp), k=1, nb)]
      allocate (lengths_in(nb))
      call comm%exchange(neighbours, lengths_out, one, lengths_in, one)
      allocate (recv_ptr(nb + 1))
      recv_ptr(1) = 1
      do k = 1, nb
         recv_ptr(k + 1) = recv_ptr(k) + nint(lengths_in(k))
      end do
      allocate (recv(recv_ptr(nb + 1) - 1))
      call comm%exchange(neighbours, send, send_ptr, recv, recv_ptr)
   end subroutine exchange_lists
end module twomem_linalg_aggregation
