!> The multigrid preconditioner of the Newton system (docs/method.md §5). With constant tensions the
!> 3N×3N system of either C-function
!>     μ1 K X1 − D X3 = r1,   μ2 K X2 + D X3 = r2,   a (X1 − X2) + b X3 = r3
!> eliminates exactly into two SPD problems for S = μ1 X1 + μ2 X2 and w = X1 − X2
!> (c_μ = 1/μ1 + 1/μ2):
!>     K S = r1 + r2,
!>     (K + c_μ D a/b) w = r1/μ1 − r2/μ2 + c_μ D r3/b   on rows with b ≠ 0 (a/b ≥ 0),
!>     w = r3/a                                          on rows with b = 0 (fixed: contact),
!> and then X3 = (r3 − a w)/b, or on fixed rows X3 = (K w − r1/μ1 + r2/μ2)/(c_μ D), and
!> X1 = (S + μ2 w)/(μ1 + μ2), X2 = (S − μ1 w)/(μ1 + μ2). Both formulas for X3 are exact with
!> the exact w; with the approximate w of a V-cycle, (r3 − a w)/b multiplies w's error by a/b
!> and the balance (ii) by K_ii/(c_μ D), so each row takes the smaller: rows whose shift
!> c_μ D a/b exceeds K_ii (Fischer–Burmeister near contact, b → 0) use the balance. (Taking
!> (r3 − a w)/b there left GMRES with no progress at all on such Newton steps.) Applying this
!> with one multigrid V-cycle for each SPD problem gives a preconditioner that would be the
!> exact inverse with exact inner solves, so GMRES on the full system needs a few iterations at
!> any mesh size, while its residual stays the full system's, which the estimators need. The S
!> hierarchy is built once per mesh; the w operator changes with the Newton step through its
!> diagonal and its fixed rows, and `set_linearization` rebuilds its coarse levels (truncated
!> at the fixed rows): only the rows its changed shifts and fixed flags reach, with K's part of
!> the coarse operators kept apart from the shift's (`multigrid_t`'s split finest operator,
!> which it applies from K: the w operator is stored only when it is solved directly). In
!> a distributed run K is each rank's part: its products are summed across ranks, and only the
!> owner of a shared row adds the diagonal shift and identity rows.
module twomem_newton_elimination
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_system, only: return_freed_memory
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_vectors, only: fill, threaded_from
   use twomem_linalg_operators, only: preconditioner_t
   use twomem_linalg_multigrid, only: multigrid_t, multigrid_options_t, multigrid_transfer_t, multigrid_work_t
   use twomem_fem_discrete, only: discrete_problem_t
   implicit none
   private

   public :: elimination_preconditioner_t

   !> A row whose added diagonal c_μ D a/b exceeds this multiple of K's diagonal is treated as
   !> fixed (w = r3/a): the difference is below round-off of the operator, and multigrid then
   !> never sees a penalty-sized entry.
   real(dp), parameter :: fixed_ratio = 1.0e12_dp

   !> What `init` was given, kept to rebuild after `release` (the caller keeps the problem and
   !> the transfers alive anyway).
   type :: build_args_t
      type(discrete_problem_t), pointer :: p => null()
      type(multigrid_transfer_t), pointer :: transfer => null()
      integer :: top = 0
      type(multigrid_options_t) :: options
   end type build_args_t

   type, extends(preconditioner_t) :: elimination_preconditioner_t
      type(build_args_t) :: args
      !> `release` has dropped everything but a and b: the next set_linearization or apply
      !> rebuilds
      logical :: released = .false.
      integer(ip) :: n = 0
      real(dp) :: mu1 = 1, mu2 = 1, c_mu = 2
      real(dp), pointer, contiguous :: mass(:) => null()
      !> the problem's stiffness K (the problem outlives the preconditioner), the interface of
      !> its rows (the transfers' finest level) and its full diagonal
      type(csr_t), pointer :: k => null()
      type(halo_t), pointer :: halo => null()
      real(dp), allocatable :: k_diag(:)
      !> the w-block operator K + c_μ D a/b with identity rows at fixed unknowns, stored only
      !> where it is solved directly (top = 0): the multigrid hierarchy applies it from K
      type(csr_t) :: w_matrix
      !> S-block (K) and w-block hierarchies, and the vectors of their V-cycles (one set: the
      !> two cycles run one after the other). Allocatable: as a plain component, gfortran 12 left
      !> its levels allocated when the preconditioner was deallocated (the valgrind test).
      type(multigrid_t) :: s_mg, w_mg
      type(multigrid_work_t), allocatable :: cycle_work
      !> the C-function rows of the current Newton matrix: a = ∂C/∂(u1 − u2), b = ∂C/∂λ
      real(dp), allocatable :: a(:), b(:)
      logical, allocatable :: fixed(:)
      !> rows whose shift or fixed flag the current Newton step changed; with a stored w_matrix,
      !> rows whose fixed flag flipped and rows of it to refill (the changed rows and the
      !> neighbours of flipped ones, whose column is cut or restored)
      logical, allocatable :: row_changed(:), flipped(:), refill(:)
      !> rows whose X3 comes from the membrane balance (ii): fixed rows and large shifts
      logical, allocatable :: by_balance(:)
      !> the w-block's shift and fixed rows as last built (none after init, when the hierarchy
      !> is the S-block's): a Newton step that leaves them alone (Newton-min once the active set
      !> is found) keeps the hierarchy, one that changes some updates the rows they reach; built
      !> is false while the hierarchy holds no valid values (it is then rebuilt whole)
      real(dp), allocatable :: shift(:)
      logical :: built = .false.
      !> positions of the diagonals of K in its value array (with a stored w_matrix)
      integer(ip), allocatable :: diag(:)
      !> work: w's right-hand side and fixed values, products with K (S, w and S's right-hand side
      !> live in the output's thirds while `apply` runs)
      real(dp), allocatable :: rhs_w(:), w_fixed(:), kw(:)
   contains
      procedure :: init
      procedure :: setup
      procedure :: set_linearization
      procedure :: apply
      procedure :: release
      procedure :: failed
   end type elimination_preconditioner_t

contains

   !> The hierarchies for problem p, on level `top` of `transfer` (top = 0: both blocks solved
   !> directly, the exact elimination). Collective.
   subroutine init(self, p, transfer, top, options, err)
      class(elimination_preconditioner_t), intent(out) :: self
      type(discrete_problem_t), target, intent(in) :: p
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      integer, intent(in) :: top
      type(multigrid_options_t), intent(in) :: options
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: n, i

      self%args = build_args_t(p, transfer, top, options)
      n = p%n
      self%n = n
      self%mu1 = p%mu1
      self%mu2 = p%mu2
      self%c_mu = 1/p%mu1 + 1/p%mu2
      self%mass => p%mass
      self%k => p%stiffness
      self%halo => transfer%halos(top)
      call self%s_mg%init(p%stiffness, transfer, top, options, .true., err)
      if (allocated(err)) return
      ! the w-block starts as the S-block (K: nothing fixed, no shift), so that even the first
      ! Newton step only recomputes the coarse rows near the contact zone; on more than one
      ! level the hierarchy applies it from K (88 bytes per unknown less)
      if (top > 0) then
         call self%w_mg%init(p%stiffness, transfer, top, options, .false., err, start_from=self%s_mg, &
                             base=p%stiffness)
      else
         self%w_matrix = p%stiffness
         call self%w_mg%init(self%w_matrix, transfer, top, options, .false., err, start_from=self%s_mg)
      end if
      if (allocated(err)) return
      ! the S-block's operator never changes, and the w-block has started from its hierarchy
      call self%s_mg%freeze()
      allocate (self%cycle_work)
      call self%cycle_work%init(self%s_mg)
      allocate (self%k_diag(n))
      !$omp parallel do default(none) shared(self, p, n) private(i) schedule(static) if(n > threaded_from)
      do i = 1, n
         self%k_diag(i) = p%stiffness%val(p%stiffness%find(i, i))
      end do
      !$omp end parallel do
      call self%halo%add(self%k_diag)
      if (top == 0) then
         allocate (self%diag(n), self%flipped(n), self%refill(n))
         do i = 1, n
            self%diag(i) = p%stiffness%find(i, i)
         end do
      end if
      allocate (self%a(n), self%b(n), self%fixed(n), self%row_changed(n), self%by_balance(n), self%shift(n), &
                self%rhs_w(n), self%w_fixed(n), self%kw(n))
      call fill(self%fixed, .false.)
      call fill(self%shift, 0.0_dp)
      self%built = self%w_mg%valid
   end subroutine init

   !> Read the C-function rows of an assembled Newton matrix (block order X1, X2, X3) and
   !> rebuild the w-block operator and its coarse levels.
   subroutine setup(self, a, err)
      class(elimination_preconditioner_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: da(:), db(:)
      integer(ip) :: n, i

      n = self%n
      if (a%n /= 3*n) then
         call make_error(err, exit_io, 'multigrid preconditioner', 'the matrix is not the Newton system it was built for')
         return
      end if
      allocate (da(n), db(n))
      do i = 1, n
         da(i) = a%val(a%find(2*n + i, i))
         db(i) = a%val(a%find(2*n + i, 2*n + i))
      end do
      call self%set_linearization(da, db, err)
   end subroutine setup

   !> The C-function Jacobian (a = ∂C/∂(u1 − u2), b = ∂C/∂λ per vertex) of the Newton step:
   !> classify the rows (fixed where b = 0, or where the shift c_μ D a/b dwarfs K's diagonal)
   !> and rebuild the w-block operator and its coarse levels, unless nothing changed on any
   !> rank. Collective.
   subroutine set_linearization(self, da, db, err)
      class(elimination_preconditioner_t), intent(inout) :: self
      real(dp), intent(in) :: da(:), db(:)
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: i
      logical :: fixed, changed, zero_row, stored

      if (self%released) then
         call restart(self, err)
         if (allocated(err)) return
      end if
      changed = .not. self%built
      zero_row = .false.
      stored = allocated(self%refill)
      !$omp parallel do default(none) shared(self, da, db, stored) private(i, fixed) reduction(.or.:changed, zero_row) &
      !$omp schedule(static) if(self%n > threaded_from)
      do i = 1, self%n
         self%a(i) = da(i)
         self%b(i) = db(i)
         if (db(i) == 0.0_dp) then
            fixed = .true.
         else
            fixed = self%c_mu*self%mass(i)*da(i)/db(i) > fixed_ratio*self%k_diag(i)
         end if
         if (fixed) then
            self%row_changed(i) = .not. self%fixed(i) .or. self%shift(i) /= 0.0_dp
            self%shift(i) = 0.0_dp
         else
            self%row_changed(i) = self%fixed(i) .or. self%shift(i) /= self%c_mu*self%mass(i)*da(i)/db(i)
            self%shift(i) = self%c_mu*self%mass(i)*da(i)/db(i)
         end if
         changed = changed .or. self%row_changed(i)
         if (stored) self%flipped(i) = fixed .neqv. self%fixed(i)
         self%fixed(i) = fixed
         self%by_balance(i) = fixed .or. self%shift(i) > self%k_diag(i)
         zero_row = zero_row .or. (fixed .and. da(i) == 0.0_dp)
      end do
      !$omp end parallel do
      if (self%halo%comm%any_true(zero_row)) then
         call make_error(err, exit_io, 'multigrid preconditioner', 'a C-function row of the Newton matrix is zero')
         return
      end if
      if (.not. self%halo%comm%any_true(changed)) return
      if (stored) then
         if (self%built) then
            self%refill = self%row_changed
            do i = 1, self%n
               if (self%flipped(i)) self%refill(self%k%col(self%k%row_ptr(i):self%k%row_ptr(i + 1) - 1)) = .true.
            end do
         else
            self%refill = .true.
         end if
         call fill_w_operator(self%k, self%diag, self%fixed, self%shift, self%halo%owned, self%refill, self%w_matrix)
      end if
      ! a failed refresh leaves the hierarchy to be rebuilt whole
      if (self%built) then
         call self%w_mg%refresh(self%fixed, err, changed=self%row_changed, shift=self%shift)
      else
         call self%w_mg%refresh(self%fixed, err, shift=self%shift)
      end if
      self%built = .not. allocated(err)
   end subroutine set_linearization

   !> w_mat = K + diag(shift) with fixed rows replaced by identity rows and fixed columns cut out,
   !> on the rows in `rows`; the shift and the identity's 1 go to the owner's part of a shared
   !> row only.
   subroutine fill_w_operator(k_mat, diag, fixed, shift, owned, rows, w_mat)
      type(csr_t), intent(in) :: k_mat
      integer(ip), intent(in) :: diag(:)
      logical, intent(in) :: fixed(:), owned(:), rows(:)
      real(dp), intent(in) :: shift(:)
      type(csr_t), intent(inout) :: w_mat

      integer(ip) :: i, k

      !$omp parallel do default(none) shared(k_mat, diag, fixed, shift, owned, rows, w_mat) private(i, k) &
      !$omp schedule(static) if(k_mat%n > threaded_from)
      do i = 1, k_mat%n
         if (.not. rows(i)) cycle
         do k = k_mat%row_ptr(i), k_mat%row_ptr(i + 1) - 1
            if (fixed(i) .or. fixed(k_mat%col(k))) then
               w_mat%val(k) = 0.0_dp
            else
               w_mat%val(k) = k_mat%val(k)
            end if
         end do
         if (fixed(i)) then
            w_mat%val(diag(i)) = merge(1.0_dp, 0.0_dp, owned(i))
         else if (owned(i)) then
            w_mat%val(diag(i)) = w_mat%val(diag(i)) + shift(i)
         end if
      end do
      !$omp end parallel do
   end subroutine fill_w_operator

   !> z ≈ A⁻¹ r by the block elimination with one V-cycle per SPD block. Collective.
   subroutine apply(self, r, z)
      class(elimination_preconditioner_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      integer(ip) :: n
      type(error_t), allocatable :: err

      if (self%released) then
         ! GMRES goes on after a release: the same preconditioner again
         call rebuild(self, err)
         if (allocated(err)) then
            ! init and set_linearization took the same data before: only a failed allocation
            ! gets here, and a zero correction makes GMRES report stagnation
            z = 0.0_dp
            return
         end if
      end if
      n = self%n
      ! S, w and S's right-hand side in z's thirds, which back_substitute overwrites row by row
      associate (s => z(1:n), w => z(n + 1:2*n), rhs_s => z(2*n + 1:3*n))
         call right_hand_sides(n, self%mu1, self%mu2, self%c_mu, self%mass, self%a, self%b, self%fixed, r, &
                               rhs_s, self%rhs_w, self%w_fixed)
         ! the fixed values enter the free rows as K_FC w_C on the right-hand side
         call fixed_coupling(self%k, self%fixed, self%w_fixed, self%kw)
         call self%halo%add(self%kw)
         call subtract_free(self%fixed, self%kw, self%rhs_w)
         call self%s_mg%vcycle(rhs_s, s, self%cycle_work)
         call self%w_mg%vcycle(self%rhs_w, w, self%cycle_work)
         call add_fixed_values(self%w_fixed, w)
         call rows_product(self%k, self%by_balance, w, self%kw)
      end associate
      call self%halo%add(self%kw)
      call back_substitute(n, self%mu1, self%mu2, self%c_mu, self%mass, self%a, self%b, self%by_balance, &
                           self%kw, r, z)
   end subroutine apply

   !> rhs_s = r1 + r2; on free rows rhs_w = r1/μ1 − r2/μ2 + c_μ D r3/b (the K_FC w_C part comes
   !> later); on fixed rows w_C = r3/a and rhs_w = 0.
   subroutine right_hand_sides(n, mu1, mu2, c_mu, mass, a, b, fixed, r, rhs_s, rhs_w, w_fixed)
      integer(ip), intent(in) :: n
      real(dp), intent(in) :: mu1, mu2, c_mu, mass(:), a(:), b(:)
      logical, intent(in) :: fixed(:)
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: rhs_s(:), rhs_w(:), w_fixed(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(n, mu1, mu2, c_mu, mass, a, b, fixed, r, rhs_s, rhs_w, w_fixed) &
      !$omp private(i) schedule(static) if(n > threaded_from)
      do i = 1, n
         rhs_s(i) = r(i) + r(n + i)
         if (fixed(i)) then
            w_fixed(i) = r(2*n + i)/a(i)
            rhs_w(i) = 0.0_dp
         else
            w_fixed(i) = 0.0_dp
            rhs_w(i) = r(i)/mu1 - r(n + i)/mu2 + c_mu*mass(i)*r(2*n + i)/b(i)
         end if
      end do
      !$omp end parallel do
   end subroutine right_hand_sides

   !> kw = this rank's part of K w_C on the free rows (w_C vanishes off the fixed rows).
   subroutine fixed_coupling(k_mat, fixed, w_fixed, kw)
      type(csr_t), intent(in) :: k_mat
      logical, intent(in) :: fixed(:)
      real(dp), intent(in) :: w_fixed(:)
      real(dp), intent(out) :: kw(:)

      integer(ip) :: i, k
      real(dp) :: t

      !$omp parallel do default(none) shared(k_mat, fixed, w_fixed, kw) private(i, k, t) schedule(static) &
      !$omp if(k_mat%n > threaded_from)
      do i = 1, k_mat%n
         t = 0.0_dp
         if (.not. fixed(i)) then
            do k = k_mat%row_ptr(i), k_mat%row_ptr(i + 1) - 1
               t = t + k_mat%val(k)*w_fixed(k_mat%col(k))
            end do
         end if
         kw(i) = t
      end do
      !$omp end parallel do
   end subroutine fixed_coupling

   !> rhs_w = rhs_w − kw on the free rows.
   subroutine subtract_free(fixed, kw, rhs_w)
      logical, intent(in) :: fixed(:)
      real(dp), intent(in) :: kw(:)
      real(dp), intent(inout) :: rhs_w(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(fixed, kw, rhs_w) private(i) schedule(static) if(size(kw) > threaded_from)
      do i = 1, size(kw, kind=ip)
         if (.not. fixed(i)) rhs_w(i) = rhs_w(i) - kw(i)
      end do
      !$omp end parallel do
   end subroutine subtract_free

   !> kw = this rank's part of K w on the rows in `rows`, 0 elsewhere.
   subroutine rows_product(k_mat, rows, w, kw)
      type(csr_t), intent(in) :: k_mat
      logical, intent(in) :: rows(:)
      real(dp), intent(in) :: w(:)
      real(dp), intent(out) :: kw(:)

      integer(ip) :: i, k
      real(dp) :: t

      !$omp parallel do default(none) shared(k_mat, rows, w, kw) private(i, k, t) &
      !$omp schedule(static) if(k_mat%n > threaded_from)
      do i = 1, k_mat%n
         t = 0.0_dp
         if (rows(i)) then
            do k = k_mat%row_ptr(i), k_mat%row_ptr(i + 1) - 1
               t = t + k_mat%val(k)*w(k_mat%col(k))
            end do
         end if
         kw(i) = t
      end do
      !$omp end parallel do
   end subroutine rows_product

   !> w = w + w_fixed (the cycle left the fixed rows at zero)
   subroutine add_fixed_values(w_fixed, w)
      real(dp), intent(in) :: w_fixed(:)
      real(dp), intent(inout) :: w(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(w_fixed, w) private(i) schedule(static) if(size(w) > threaded_from)
      do i = 1, size(w, kind=ip)
         w(i) = w(i) + w_fixed(i)
      end do
      !$omp end parallel do
   end subroutine add_fixed_values

   !> z from S and w, which it holds on entry as [S; w; ·]: X3 from the C-function row or from
   !> the balance (ii) (kw = K w on those rows), then X1, X2.
   subroutine back_substitute(n, mu1, mu2, c_mu, mass, a, b, by_balance, kw, r, z)
      integer(ip), intent(in) :: n
      real(dp), intent(in) :: mu1, mu2, c_mu, mass(:), a(:), b(:)
      logical, intent(in) :: by_balance(:)
      real(dp), intent(in) :: kw(:), r(:)
      real(dp), intent(inout) :: z(:)

      integer(ip) :: i
      real(dp) :: s, w

      !$omp parallel do default(none) shared(n, mu1, mu2, c_mu, mass, a, b, by_balance, kw, r, z) &
      !$omp private(i, s, w) schedule(static) if(n > threaded_from)
      do i = 1, n
         s = z(i)
         w = z(n + i)
         if (by_balance(i)) then
            z(2*n + i) = (kw(i) - r(i)/mu1 + r(n + i)/mu2)/(c_mu*mass(i))
         else
            z(2*n + i) = (r(2*n + i) - a(i)*w)/b(i)
         end if
         z(i) = (s + mu2*w)/(mu1 + mu2)
         z(n + i) = (s - mu1*w)/(mu1 + mu2)
      end do
      !$omp end parallel do
   end subroutine back_substitute

   !> Keep only what a rebuild needs (the problem, the prolongations and the C-function rows a,
   !> b of the current Newton step): the hierarchies, the w-block operator, the rows' flags and
   !> work vectors and the transfers' restrictions go, about 0.4 KiB per vertex. The next
   !> set_linearization or apply builds them again as init and set_linearization do, which
   !> gives the bits of the hierarchy updated step by step (test_partial_rebuild): a release
   !> changes the memory, not the iterates. It costs a rebuild when the preconditioner is
   !> applied again.
   subroutine release(self)
      class(elimination_preconditioner_t), intent(inout) :: self

      type(build_args_t) :: args
      real(dp), allocatable :: a(:), b(:)

      if (self%released .or. .not. associated(self%args%p)) return
      args = self%args
      call move_alloc(self%a, a)
      call move_alloc(self%b, b)
      ! explicitly: gfortran 12 leaves a plain multigrid_t component's levels allocated when
      ! its owner is reset (see the type)
      call self%s_mg%free()
      call self%w_mg%free()
      ! no multigrid uses them until the rebuild, which transposes P again
      call args%transfer%drop_restrictions()
      call reset(self)
      self%args = args
      call move_alloc(a, self%a)
      call move_alloc(b, self%b)
      self%released = .true.
      ! the next large arrays (the algebraic flux's) do not fit the holes left here
      call return_freed_memory()
   end subroutine release

   !> Every component deallocated or back to its default.
   subroutine reset(self)
      type(elimination_preconditioner_t), intent(out) :: self
   end subroutine reset

   !> After `release`: the preconditioner of `init` again (the hierarchies of K, nothing fixed).
   !> Collective.
   subroutine restart(self, err)
      type(elimination_preconditioner_t), intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      type(build_args_t) :: args

      args = self%args
      call self%init(args%p, args%transfer, args%top, args%options, err)
   end subroutine restart

   !> After `release`: the preconditioner of the released Newton step (its rows a, b) again. A
   !> failure leaves it released, with those rows, for the next attempt. Collective.
   subroutine rebuild(self, err)
      type(elimination_preconditioner_t), intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      real(dp), allocatable :: a(:), b(:)

      call move_alloc(self%a, a)
      call move_alloc(self%b, b)
      call restart(self, err)
      if (.not. allocated(err)) call self%set_linearization(a, b, err)
      if (allocated(err)) then
         call move_alloc(a, self%a)
         call move_alloc(b, self%b)
         self%released = .true.
      end if
   end subroutine rebuild

   !> A coarse solve failed after its factorization had succeeded (the cycles then return 0).
   logical function failed(self)
      class(elimination_preconditioner_t), intent(in) :: self

      failed = self%s_mg%failed .or. self%w_mg%failed
   end function failed
end module twomem_newton_elimination
