!> Geometric multigrid for symmetric positive definite operators on a nested hierarchy: the
!> V-cycle that preconditions the two SPD blocks of the Newton system (docs/method.md §5). It knows
!> no PDE: the caller hands it the finest operator and the prolongations between consecutive
!> levels (`multigrid_transfer_t` of twomem_linalg_mg_transfer, built once per hierarchy and
!> shared by every cycle on it); the coarse operators are the Galerkin products P_lᵀ A_l P_l,
!> smoothing is Chebyshev–Jacobi (pre and post, same degree, so the cycle is symmetric), and
!> the coarsest level is solved by UMFPACK (on rank 0 of a distributed run, the level gathered
!> there: it is small). In a
!> distributed run every level holds each rank's part of the operator and the interface of its
!> unknowns (`halos`): products sum the parts across ranks, a residual is restricted from the
!> entries each rank owns and summed on the coarse interface, and prolongation is local, since
!> a rank's fine unknowns have their coarse parents on the same rank. Unknowns may be fixed
!> (Dirichlet rows of the finest operator): their prolongation rows are truncated, and a coarse
!> unknown is fixed when the fine unknown it is injected into is, so no coarse level ever moves
!> a fixed unknown and every coarse operator stays SPD on its free unknowns in exact arithmetic
!> (truncated algebraic levels can be singular to round-off: `coarsest_shift`). The patterns are
!> analysed once (`init`); new values or a new fixed set only redo the numeric products, the
!> smoothers' diagonals and the coarse factorization (`refresh`).
!> A refresh told which finest rows changed recomputes only the coarse rows those changes and
!> the flipped fixed flags can reach, level by level (a Newton step moves the active set near
!> the free boundary only), with the bits of a full rebuild. And a finest operator that is a
!> fixed `base` plus a diagonal shift (the Newton w-block, whose shift changes everywhere at
!> every Fischer–Burmeister step) keeps Pᵀ base P apart: only the rows a flipped fixed flag
!> reaches are recomputed there, and the shift's part Pᵀ D P costs a small fraction of a product
!> with the base. Such an operator is never stored either: the cycle applies base cut at the
!> fixed unknowns with its own diagonal (`csr_t%cut_matvec`), with the bits of the stored matrix.
module twomem_linalg_multigrid
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_galerkin, only: galerkin_pattern, galerkin_assemble, galerkin_rows, galerkin_diagonal_rows, &
                                     cut_rows, touched_rows, truncate_transfer
   use twomem_linalg_chebyshev, only: chebyshev_t, level_product, uncut_diagonal, uncut_fixed
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_gathered_solve, only: gathered_solver_t
   use twomem_linalg_umfpack, only: ordering_minimum_degree
   use twomem_linalg_vectors, only: copy_allocated, fill, threaded_from
   use twomem_linalg_mg_transfer, only: multigrid_transfer_t
   implicit none
   private

   public :: multigrid_t, multigrid_options_t, multigrid_transfer_t, multigrid_work_t

   !> The coarsest level below the finest is factorized with its diagonal times 1 + this. Truncated
   !> smoothed-aggregation prolongations can make coarse basis functions linearly dependent on
   !> the free unknowns (aggregates overlapping at a few free vertices inside a contact zone):
   !> the Galerkin operator is then singular to round-off, and UMFPACK's solve amplified its
   !> round-off into corrections of 10^20 and more along the dependent combinations, which GMRES
   !> met as a breakdown or a stalled Newton (26 steps instead of 2 on an adaptive step of the
   !> pacman benchmark with adapt.theta = 0.7). Those combinations prolong to (nearly) zero, so
   !> the shift only bounds them; elsewhere it changes the coarse correction by 1e-10 relative.
   real(dp), parameter :: coarsest_shift = 1.0e-10_dp

   type :: multigrid_options_t
      !> Chebyshev degree of the pre- and of the post-smoothing
      integer :: degree = 2
      !> the smoothers damp the eigenvalues of D⁻¹A in [λ_max/ratio, λ_max]
      real(dp) :: ratio = 4.0_dp
   end type multigrid_options_t

   type :: mg_level_t
      !> the operator of a coarse level (the finest is the caller's)
      type(csr_t) :: a
      !> P and R values from the next coarser level, truncated at fixed unknowns (levels ≥ 1,
      !> allocated once some unknown is fixed)
      real(dp), allocatable :: pt(:), rt(:)
      logical, allocatable :: fixed(:)
      !> rows whose values the current refresh changed
      logical, allocatable :: updated(:)
      !> coarse levels: this rank's part of each row's diagonal as computed and the rows made
      !> identity rows (`cut_rows`); below a split finest level, the values of Pᵀ base P
      real(dp), allocatable :: part_diag(:), base_part(:)
      logical, allocatable :: cut(:)
      type(chebyshev_t) :: smoother
   end type mg_level_t

   !> One level's vectors of a V-cycle: right-hand side and iterate (below the finest, whose are
   !> the caller's) and three work vectors (above the coarsest).
   type :: level_work_t
      real(dp), allocatable :: b(:), x(:), r1(:), r2(:), r3(:)
   end type level_work_t

   !> The vectors a V-cycle writes, kept apart from the hierarchy's operators so that two
   !> hierarchies on the same levels that never cycle at the same time (the S and w blocks of
   !> the Newton preconditioner) can share one: at 10⁶ unknowns that is 37 MB less.
   type :: multigrid_work_t
      private
      type(level_work_t), allocatable :: levels(:)
   contains
      procedure :: init => work_init
   end type multigrid_work_t

   type :: multigrid_t
      !> the finest level; levels(0) is solved directly
      integer :: top = -1
      !> the finest operator and the transfers, kept alive by the caller
      type(csr_t), pointer :: finest => null()
      type(multigrid_transfer_t), pointer :: transfer => null()
      !> the finest operator's fixed part, when it is base + diag(shift) (see `refresh`); that
      !> operator is then never stored: it is base cut at the fixed unknowns with the diagonal
      !> `cut_diagonal` (csr_t%cut_matvec), 8 bytes per unknown instead of a matrix
      type(csr_t), pointer :: base => null()
      real(dp), allocatable :: cut_diagonal(:)
      !> the coarse levels hold the values of the last refresh (a refresh can then be partial)
      logical :: valid = .false.
      !> `freeze` dropped what only a refresh reads: the operator may no longer change
      logical :: frozen = .false.
      type(mg_level_t), allocatable :: levels(:)
      type(multigrid_options_t) :: options
      type(gathered_solver_t) :: coarse
      !> the cycle's vectors when the caller passes none (allocated at the first such cycle;
      !> allocatable, since gfortran 12 does not free a plain component's levels with its owner)
      type(multigrid_work_t), allocatable :: own_work
      !> set if a coarse solve failed after its factorization had succeeded (misuse): the
      !> cycle then returns zero, which GMRES reports as stagnation
      logical :: failed = .false.
   contains
      procedure :: init
      procedure :: refresh
      procedure :: freeze
      procedure :: vcycle
      procedure :: free
   end type multigrid_t

contains

   !> The hierarchy for the finest operator `finest` on levels 0..top of `transfer` (top = 0: a
   !> direct solve). With `start_from` (a refreshed multigrid on the same transfer, levels and
   !> finest pattern, with no fixed unknown) the coarse patterns and values are copied from it:
   !> the hierarchy is then ready for a finest operator equal to start_from's, and the first
   !> refresh can be partial (the w-block starts as the S-block: K, nothing fixed, no shift).
   !> Otherwise, with `assemble`, init builds the levels for no fixed unknown (what `refresh`
   !> would, patterns and values together); without, it analyses the patterns and the caller
   !> refreshes when it has the values. The caller keeps
   !> `finest` and `transfer` alive and in place while the multigrid is used. With `base` (kept
   !> alive too; `finest` is then base itself, and top > 0), every refresh's finest operator is
   !> base plus a diagonal shift on its free unknowns, cut at the fixed ones (see `refresh`); the
   !> operator starts as base. Collective.
   subroutine init(self, finest, transfer, top, options, assemble, err, start_from, base)
      class(multigrid_t), intent(inout) :: self
      type(csr_t), target, intent(in) :: finest
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      integer, intent(in) :: top
      type(multigrid_options_t), intent(in) :: options
      logical, intent(in) :: assemble
      type(error_t), allocatable, intent(out) :: err
      type(multigrid_t), intent(in), optional :: start_from
      type(csr_t), target, intent(in), optional :: base

      integer :: l
      integer(ip) :: n, i
      logical :: fused

      call self%free()
      call transfer%restore_restrictions()
      if (top < 0 .or. top > transfer%levels .or. .not. allocated(transfer%halos)) then
         call make_error(err, exit_io, 'multigrid', 'the operator does not match a level of the hierarchy')
         return
      end if
      self%options = options
      self%top = top
      self%finest => finest
      self%transfer => transfer
      allocate (self%levels(0:top))
      ! a hierarchy assembled here gets each level's pattern and values in one pass
      fused = assemble .and. .not. present(start_from) .and. .not. present(base)
      if (.not. fused) then
         do l = top, 1, -1
            if (present(start_from)) then
               ! pattern and values (`start_as` keeps the values when the start can serve)
               call self%levels(l - 1)%a%copy_from(start_from%levels(l - 1)%a)
            else if (l == top) then
               call galerkin_pattern(transfer%r(l), finest, transfer%p(l), self%levels(l - 1)%a)
            else
               call galerkin_pattern(transfer%r(l), self%levels(l)%a, transfer%p(l), self%levels(l - 1)%a)
            end if
         end do
      end if
      do l = 0, top
         n = finest%n
         if (l < top) n = transfer%p(l + 1)%ncol
         associate (lev => self%levels(l))
            allocate (lev%fixed(n))
            if (l < top) allocate (lev%part_diag(n), lev%cut(n))
            allocate (lev%updated(n))
            call fill(lev%fixed, .false.)
            if (l < top) call fill(lev%cut, .false.)
         end associate
      end do
      if (present(base) .and. top > 0) then
         self%base => base
         allocate (self%levels(top - 1)%base_part(self%levels(top - 1)%a%nnz()))
         allocate (self%cut_diagonal(base%n))
         !$omp parallel do default(none) shared(self, base) private(i) schedule(static) if(base%n > threaded_from)
         do i = 1, base%n
            self%cut_diagonal(i) = base%val(base%find(i, i))
         end do
         !$omp end parallel do
      end if
      call self%coarse%init(transfer%halos(0)%comm, transfer%coarse_keys, transfer%halos(0)%owned, &
                            ordering=ordering_minimum_degree, diagonal_shift=merge(coarsest_shift, 0.0_dp, top > 0))
      if (present(start_from)) then
         call start_as(self, start_from, err)
      else if (fused) then
         call assemble_levels(self, err)
      else if (assemble) then
         call self%refresh(self%levels(top)%fixed, err)
      end if
   end subroutine init

   !> The coarse levels for nothing fixed, what `refresh` computes, but each level's pattern and
   !> values in one pass (`galerkin_assemble`) instead of a pattern pass and a product.
   subroutine assemble_levels(self, err)
      type(multigrid_t), intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      integer(ip), allocatable :: rows(:), regain(:)
      integer(ip) :: i
      integer :: l

      do l = self%top, 1, -1
         associate (fine => self%levels(l), coarse => self%levels(l - 1), p => self%transfer%p(l), &
                    r => self%transfer%r(l), halo => self%transfer%halos(l))
            if (l == self%top) then
               call galerkin_assemble(r, self%finest, p, coarse%a)
               call fine%smoother%setup(self%finest, halo, self%options%degree, self%options%ratio)
            else
               call galerkin_assemble(r, fine%a, p, coarse%a)
               call fine%smoother%setup(fine%a, halo, self%options%degree, self%options%ratio)
            end if
            rows = [(i, i=1, coarse%a%n)]
            coarse%updated = .true.
            call cut_rows(rows, coarse%fixed, self%transfer%halos(l - 1), coarse%part_diag, coarse%cut, coarse%a, &
                          coarse%updated, regain)
         end associate
      end do
      call factor_coarsest(self, err)
      self%valid = .not. allocated(err)
   end subroutine assemble_levels

   !> The coarse values, smoothers and coarsest factorization of `start`, whose patterns init
   !> copied already. A start that cannot serve (not refreshed, or with fixed unknowns, or
   !> without the uncut values of Pᵀ base P) leaves the first refresh to rebuild everything.
   subroutine start_as(self, start, err)
      type(multigrid_t), intent(inout) :: self
      type(multigrid_t), intent(in) :: start
      type(error_t), allocatable, intent(out) :: err

      integer :: l, top
      logical :: usable

      top = self%top
      usable = start%valid .and. .not. start%frozen .and. start%top == top
      if (usable) usable = .not. any(start%levels(top)%fixed)
      if (usable .and. associated(self%base)) then
         associate (below => start%levels(top - 1))
            usable = allocated(below%base_part) .or. .not. any(below%cut)
         end associate
      end if
      if (self%transfer%halos(top)%comm%any_true(.not. usable)) return
      ! (init copied the coarse operators, values included)
      do l = 0, top
         associate (lev => self%levels(l), src => start%levels(l))
            if (l < top) then
               call copy_allocated(src%part_diag, lev%part_diag)
               call copy_allocated(src%cut, lev%cut)
            end if
            if (l > 0) call lev%smoother%copy_from(src%smoother)
         end associate
      end do
      if (associated(self%base)) then
         associate (below => start%levels(top - 1))
            if (allocated(below%base_part)) then
               call copy_allocated(below%base_part, self%levels(top - 1)%base_part)
            else
               call copy_allocated(below%a%val, self%levels(top - 1)%base_part)
            end if
         end associate
      end if
      call factor_coarsest(self, err)
      self%valid = .not. allocated(err)
   end subroutine start_as

   !> Recompute the coarse levels from the finest operator's current values and its fixed
   !> unknowns, whose rows in the finest operator must be identity rows with zero columns (as
   !> they are in the cut operator of a split one).
   !> `changed` marks the finest rows whose values changed since the last refresh other than by
   !> a flipped fixed flag (the flipped rows and their columns are found here): then only the
   !> coarse rows they reach are recomputed, without it every row is. With a `base` (init),
   !> `shift` is the diagonal the finest operator adds to base on its free unknowns, on the
   !> entries this rank owns. Collective.
   subroutine refresh(self, fixed, err, changed, shift)
      class(multigrid_t), intent(inout) :: self
      logical, intent(in) :: fixed(:)
      type(error_t), allocatable, intent(out) :: err
      logical, intent(in), optional :: changed(:)
      real(dp), intent(in), optional :: shift(:)

      integer :: l
      logical :: truncated, partial, refactor
      logical, allocatable :: flipped(:), coarse_flipped(:)

      if (self%frozen) then
         call make_error(err, exit_io, 'multigrid', 'a frozen hierarchy was refreshed')
         return
      end if
      partial = self%valid .and. present(changed)
      self%valid = .false.
      associate (finest => self%levels(self%top))
         if (partial) then
            flipped = fixed .neqv. finest%fixed
            finest%updated = changed .or. flipped
            ! a flipped unknown's column is cut or restored: its neighbours' rows change too
            call mark_neighbours(self%finest, flipped, finest%updated)
         else
            allocate (flipped(size(fixed)))
            flipped = .true.
            finest%updated = .true.
         end if
         finest%fixed = fixed
      end associate
      if (associated(self%base)) then
         if (.not. present(shift)) then
            call make_error(err, exit_io, 'multigrid', 'a split finest operator needs its shift')
            return
         end if
         call set_cut_diagonal(self%base, shift, fixed, self%transfer%halos(self%top)%owned, self%cut_diagonal)
      end if
      truncated = any(fixed)
      do l = self%top, 1, -1
         if (l == self%top) then
            call coarsen(self, l, truncated, flipped, coarse_flipped, self%finest, shift)
         else
            call coarsen(self, l, truncated, flipped, coarse_flipped, self%levels(l)%a)
         end if
         call move_alloc(coarse_flipped, flipped)
      end do
      ! the coarsest factorization is the one step whose cost does not shrink with the change
      refactor = self%transfer%halos(0)%comm%any_true(any(self%levels(0)%updated))
      if (refactor .or. .not. partial) call factor_coarsest(self, err)
      self%valid = .not. allocated(err)
   end subroutine refresh

   !> Drop what only `refresh` reads: the levels' fixed flags and row marks, the coarse rows'
   !> diagonal parts and cut flags, the smoothers' row parts (about 36 bytes per finest unknown).
   !> For a hierarchy whose operator never changes (the S-block), once every hierarchy that
   !> starts from it (`init`'s start_from) has been made; the V-cycle needs none of it.
   subroutine freeze(self)
      class(multigrid_t), intent(inout) :: self

      integer :: l

      if (.not. allocated(self%levels)) return
      do l = 0, self%top
         associate (lev => self%levels(l))
            if (allocated(lev%fixed)) deallocate (lev%fixed)
            if (allocated(lev%updated)) deallocate (lev%updated)
            if (allocated(lev%part_diag)) deallocate (lev%part_diag)
            if (allocated(lev%cut)) deallocate (lev%cut)
            if (allocated(lev%smoother%part_diag)) deallocate (lev%smoother%part_diag, lev%smoother%part_sum)
         end associate
      end do
      self%frozen = .true.
   end subroutine freeze

   !> The diagonal of the split finest operator: an identity row's 1 at a fixed unknown (0 in a
   !> part that another rank owns), base's diagonal plus the shift at a free one (the shift on
   !> the owner's part alone).
   subroutine set_cut_diagonal(base, shift, fixed, owned, diagonal)
      type(csr_t), intent(in) :: base
      real(dp), intent(in) :: shift(:)
      logical, intent(in) :: fixed(:), owned(:)
      real(dp), intent(out) :: diagonal(:)

      integer(ip) :: i
      real(dp) :: d

      !$omp parallel do default(none) shared(base, shift, fixed, owned, diagonal) private(i, d) schedule(static) &
      !$omp if(base%n > threaded_from)
      do i = 1, base%n
         if (fixed(i)) then
            diagonal(i) = merge(1.0_dp, 0.0_dp, owned(i))
         else
            d = base%val(base%find(i, i))
            if (owned(i)) d = d + shift(i)
            diagonal(i) = d
         end if
      end do
      !$omp end parallel do
   end subroutine set_cut_diagonal

   !> The direct factorization of the coarsest level (the finest operator itself when there is
   !> one level), its failure told as the multigrid's.
   subroutine factor_coarsest(self, err)
      type(multigrid_t), intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      if (self%top == 0) then
         call self%coarse%factor(self%finest, err)
      else
         call self%coarse%factor(self%levels(0)%a, err)
      end if
      if (allocated(err)) call make_error(err, exit_io, 'multigrid', 'coarsest level: '//err%message)
   end subroutine factor_coarsest

   !> Level l−1 from level l (operator a) on the rows the changes reach: its fixed unknowns, the
   !> truncated transfer values (when a fixed flag flipped), the Galerkin product, and the
   !> smoother of level l (on level l's updated rows). `flipped` marks level l's unknowns whose
   !> fixed flag flipped, `coarse_flipped` returns level l−1's.
   !> Below a nested level a coarse unknown is fixed where the fine unknown it is injected into
   !> is. An aggregation level has no such unknown: there the coarse unknowns whose truncated
   !> basis function vanished (identity rows, `cut_rows`) count as fixed for the next coarsening,
   !> so that the identity rows, which stand for no fine function, add nothing to the coarser
   !> Galerkin products.
   subroutine coarsen(self, l, truncated, flipped, coarse_flipped, a, shift)
      type(multigrid_t), intent(inout) :: self
      integer, intent(in) :: l
      logical, intent(in) :: truncated
      logical, intent(in) :: flipped(:)
      logical, allocatable, intent(out) :: coarse_flipped(:)
      type(csr_t), intent(in) :: a
      real(dp), intent(in), optional :: shift(:)

      logical, allocatable :: was_cut(:)
      logical :: fresh, nested

      nested = l > self%transfer%algebraic
      associate (fine => self%levels(l), coarse => self%levels(l - 1), p => self%transfer%p(l), &
                 r => self%transfer%r(l))
         if (nested) then
            coarse%fixed = fine%fixed(self%transfer%injection(l)%i)
            coarse_flipped = flipped(self%transfer%injection(l)%i)
         else
            call move_alloc(coarse%fixed, was_cut)
            allocate (coarse%fixed(size(was_cut)), coarse_flipped(size(was_cut)))
            call fill(coarse%fixed, .false.)
            call fill(coarse_flipped, .false.)
         end if
         if (truncated) then
            fresh = .not. allocated(fine%pt)
            if (fresh) allocate (fine%pt(p%nnz()), fine%rt(r%nnz()))
            if (fresh .or. any(flipped)) call truncate_transfer(p, r, fine%fixed, coarse%fixed, fine%pt, fine%rt)
            call coarse_rows(self, l, a, fine%rt, fine%pt, flipped, coarse_flipped, shift)
         else
            ! no fixed unknown (any more): the transfer's own values
            if (allocated(fine%pt)) deallocate (fine%pt, fine%rt)
            call coarse_rows(self, l, a, r%val, p%val, flipped, coarse_flipped, shift)
         end if
         if (.not. nested) then
            coarse%fixed = coarse%cut
            coarse_flipped = coarse%cut .neqv. was_cut
         end if
         if (l == self%top .and. associated(self%base)) then
            call fine%smoother%setup(a, self%transfer%halos(l), self%options%degree, self%options%ratio, &
                                     row_list(fine%updated), self%cut_diagonal, fine%fixed)
         else
            call fine%smoother%setup(a, self%transfer%halos(l), self%options%degree, self%options%ratio, &
                                     row_list(fine%updated))
         end if
      end associate
   end subroutine coarsen

   !> The rows of level l−1's operator that the flipped fixed flags and level l's updated rows
   !> reach, recomputed with the transfer values rv, pv; below a split finest operator as
   !> Pᵀ base P (only where a flag flipped) plus Pᵀ diag(shift) P.
   subroutine coarse_rows(self, l, a, rv, pv, flipped, coarse_flipped, shift)
      type(multigrid_t), intent(inout) :: self
      integer, intent(in) :: l
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: rv(:), pv(:)
      logical, intent(in) :: flipped(:), coarse_flipped(:)
      real(dp), intent(in), optional :: shift(:)

      integer(ip), allocatable :: rows(:), regain(:)
      logical, allocatable :: no_change(:)
      logical :: split

      split = l == self%top .and. associated(self%base)
      associate (fine => self%levels(l), coarse => self%levels(l - 1), p => self%transfer%p(l), &
                 r => self%transfer%r(l))
         if (split) then
            allocate (no_change(size(flipped)))
            no_change = .false.
            call touched_rows(r, self%base, p, coarse_flipped, flipped, no_change, coarse%updated)
            rows = row_list(coarse%updated)
            call galerkin_rows(r, rv, self%base, p, pv, rows, coarse%a%row_ptr, coarse%a%col, coarse%base_part)
         end if
         call touched_rows(r, a, p, coarse_flipped, flipped, fine%updated, coarse%updated)
         rows = row_list(coarse%updated)
         call product(rows)
         call cut_rows(rows, coarse%fixed, self%transfer%halos(l - 1), coarse%part_diag, coarse%cut, coarse%a, &
                       coarse%updated, regain)
         ! only in a distributed run: rows another rank's change brought back from identity rows
         if (size(regain) > 0) call product(regain)
      end associate

   contains

      subroutine product(list)
         integer(ip), intent(in) :: list(:)

         associate (coarse => self%levels(l - 1), p => self%transfer%p(l), r => self%transfer%r(l))
            if (split) then
               call galerkin_diagonal_rows(r, rv, shift, self%transfer%halos(l)%owned, self%levels(l)%fixed, p, pv, &
                                           list, coarse%a%row_ptr, coarse%a%col, coarse%a%val, coarse%base_part)
            else
               call galerkin_rows(r, rv, a, p, pv, list, coarse%a%row_ptr, coarse%a%col, coarse%a%val)
            end if
         end associate
      end subroutine product
   end subroutine coarse_rows

   !> marks(j) = .true. for every neighbour j (in a's symmetric pattern) of an unknown in `seeds`.
   subroutine mark_neighbours(a, seeds, marks)
      type(csr_t), intent(in) :: a
      logical, intent(in) :: seeds(:)
      logical, intent(inout) :: marks(:)

      integer(ip) :: i

      do i = 1, a%n
         if (seeds(i)) marks(a%col(a%row_ptr(i):a%row_ptr(i + 1) - 1)) = .true.
      end do
   end subroutine mark_neighbours

   !> The indices of the true entries of `mask`.
   function row_list(mask) result(rows)
      logical, intent(in) :: mask(:)
      integer(ip), allocatable :: rows(:)

      integer(ip) :: i

      rows = pack([(i, i=1, size(mask, kind=ip))], mask)
   end function row_list

   !> x = one V-cycle applied to b, from a zero initial guess, with the vectors of `work` (made by
   !> `work%init` for this hierarchy or one on the same levels) or, without, the hierarchy's own.
   !> b (full values at shared unknowns) must vanish at the fixed unknowns; x then does too.
   !> Collective.
   subroutine vcycle(self, b, x, work)
      class(multigrid_t), intent(inout) :: self
      real(dp), intent(in) :: b(:)
      real(dp), intent(out) :: x(:)
      type(multigrid_work_t), intent(inout), optional :: work

      if (present(work)) then
         call cycle_level(self, self%top, b, x, work)
      else
         if (.not. allocated(self%own_work)) then
            allocate (self%own_work)
            call self%own_work%init(self)
         end if
         call cycle_level(self, self%top, b, x, self%own_work)
      end if
   end subroutine vcycle

   !> The vectors of a V-cycle on the levels of `mg`.
   subroutine work_init(self, mg)
      class(multigrid_work_t), intent(out) :: self
      type(multigrid_t), intent(in) :: mg

      integer :: l
      integer(ip) :: n

      allocate (self%levels(0:mg%top))
      do l = 0, mg%top
         n = mg%finest%n
         if (l < mg%top) n = mg%transfer%p(l + 1)%ncol
         associate (lev => self%levels(l))
            if (l < mg%top) allocate (lev%b(n), lev%x(n))
            if (l > 0) allocate (lev%r1(n), lev%r2(n), lev%r3(n))
         end associate
      end do
   end subroutine work_init

   recursive subroutine cycle_level(self, l, b, x, work)
      type(multigrid_t), intent(inout) :: self
      integer, intent(in) :: l
      real(dp), intent(in) :: b(:)
      real(dp), intent(out) :: x(:)
      type(multigrid_work_t), intent(inout) :: work

      type(error_t), allocatable :: err

      if (l == 0) then
         call self%coarse%solve(b, x, err)
         if (allocated(err)) then
            x = 0.0_dp
            self%failed = .true.
         end if
      else if (l == self%top .and. associated(self%base)) then
         call two_grid_step(self, l, self%finest, b, x, work, self%cut_diagonal, self%levels(l)%fixed)
      else if (l == self%top) then
         call two_grid_step(self, l, self%finest, b, x, work, uncut_diagonal, uncut_fixed)
      else
         call two_grid_step(self, l, self%levels(l)%a, b, x, work, uncut_diagonal, uncut_fixed)
      end if
   end subroutine cycle_level

   !> Pre-smoothing, the coarse correction by a cycle on level l−1, post-smoothing; on the
   !> operator `a`, cut by `diagonal` and `fixed` on the split finest level, else with
   !> uncut_diagonal and uncut_fixed (level_product).
   recursive subroutine two_grid_step(self, l, a, b, x, work, diagonal, fixed)
      type(multigrid_t), intent(inout) :: self
      integer, intent(in) :: l
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: b(:)
      real(dp), intent(out) :: x(:)
      type(multigrid_work_t), intent(inout) :: work
      real(dp), intent(in) :: diagonal(:)
      logical, intent(in) :: fixed(:)

      associate (lev => self%levels(l), p => self%transfer%p(l), r => self%transfer%r(l), &
                 halo => self%transfer%halos(l), v => work%levels(l), below => work%levels(l - 1))
         call lev%smoother%smooth(a, halo, b, x, .true., v%r1, v%r2, v%r3, diagonal, fixed)
         call level_product(a, halo, x, v%r3, diagonal, fixed)
         ! the residual from the entries this rank owns: the ranks' restrictions then add up
         call owned_residual(b, v%r3, halo%owned, v%r1)
         if (allocated(lev%rt)) then
            call restrict(r, lev%rt, v%r1, below%b)
         else
            call restrict(r, r%val, v%r1, below%b)
         end if
         call self%transfer%halos(l - 1)%add(below%b)
         call cycle_level(self, l - 1, below%b, below%x, work)
         if (allocated(lev%pt)) then
            call prolong_add(p, lev%pt, below%x, x)
         else
            call prolong_add(p, p%val, below%x, x)
         end if
         call lev%smoother%smooth(a, halo, b, x, .false., v%r1, v%r2, v%r3, diagonal, fixed)
      end associate
   end subroutine two_grid_step

   !> r = b − ax on the owned entries, 0 elsewhere.
   subroutine owned_residual(b, ax, owned, r)
      real(dp), intent(in) :: b(:), ax(:)
      logical, intent(in) :: owned(:)
      real(dp), intent(out) :: r(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(b, ax, owned, r) private(i) schedule(static) if(size(r) > threaded_from)
      do i = 1, size(r, kind=ip)
         r(i) = merge(b(i) - ax(i), 0.0_dp, owned(i))
      end do
      !$omp end parallel do
   end subroutine owned_residual

   !> bc = R r with R's pattern and the values `rv`.
   subroutine restrict(r, rv, res, bc)
      type(csr_t), intent(in) :: r
      real(dp), intent(in) :: rv(:), res(:)
      real(dp), intent(out) :: bc(:)

      integer(ip) :: j, k
      real(dp) :: s

      !$omp parallel do default(none) shared(r, rv, res, bc) private(j, k, s) schedule(static) if(r%n > threaded_from)
      do j = 1, r%n
         s = 0.0_dp
         do k = r%row_ptr(j), r%row_ptr(j + 1) - 1
            s = s + rv(k)*res(r%col(k))
         end do
         bc(j) = s
      end do
      !$omp end parallel do
   end subroutine restrict

   !> x = x + P xc with P's pattern and the values `pv`.
   subroutine prolong_add(p, pv, xc, x)
      type(csr_t), intent(in) :: p
      real(dp), intent(in) :: pv(:), xc(:)
      real(dp), intent(inout) :: x(:)

      integer(ip) :: i, k

      !$omp parallel do default(none) shared(p, pv, xc, x) private(i, k) schedule(static) if(p%n > threaded_from)
      do i = 1, p%n
         do k = p%row_ptr(i), p%row_ptr(i + 1) - 1
            x(i) = x(i) + pv(k)*xc(p%col(k))
         end do
      end do
      !$omp end parallel do
   end subroutine prolong_add

   subroutine free(self)
      class(multigrid_t), intent(inout) :: self

      if (allocated(self%levels)) deallocate (self%levels)
      if (allocated(self%own_work)) deallocate (self%own_work)
      if (allocated(self%cut_diagonal)) deallocate (self%cut_diagonal)
      self%top = -1
      self%finest => null()
      self%transfer => null()
      self%base => null()
      self%valid = .false.
      self%frozen = .false.
      self%failed = .false.
   end subroutine free
end module twomem_linalg_multigrid
