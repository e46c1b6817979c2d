!> The semismooth Newton driver. Each step linearizes the C-function at the current iterate,
!> solves the Newton system (exactly with UMFPACK, or by GMRES) and checks the paper's stopping
!> test ‖R_lin‖/‖[F;0]‖ ≤ tol with R_lin = [F − E X; −C(X)] (DESIGN.md §2). With GMRES and
!> the paper's forcing, GMRES stops as soon as its relative algebraic residual is below the
!> relative linearization residual of its current iterate, checked every ν iterations (the
!> paper's inexact method). The adaptive mode is the paper's Algorithm 1: every ν GMRES
!> iterations the observer evaluates the a posteriori estimators; GMRES stops when
!> η_alg ≤ γ_alg max(η_disc, η_lin) and Newton when η_lin ≤ γ_lin η_disc (eq. (63)), or on the
!> local criteria (64) when asked. An optional backtracking line search on ‖R_lin‖ keeps Newton from
!> cycling or diverging (on by default for Fischer–Burmeister). The driver stops with a
!> reason at the step limit, when exact Newton-min revisits an active set (cycling) or when
!> the active set stops changing with the residual above the tolerance (round-off floor).
!> What the caller wants to know about an iterate beyond residuals (exact errors, later
!> estimators) it computes in an observer.
module twomem_newton_solver
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_is_nan, ieee_is_finite, ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_timer, only: wall_time
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_gmres, only: gmres_options_t, gmres_observer_t
   use twomem_newton_cfun, only: cfun_eval
   use twomem_newton_system, only: newton_system_t
   use twomem_newton_linear, only: linear_step_t
   use twomem_newton_history, only: history_t, history_row_t, not_computed
   implicit none
   private

   public :: newton_options_t, newton_result_t, newton_observer_t, newton_solve

   type :: newton_options_t
      character(len=8) :: cfun = 'min'
      !> 'direct' (UMFPACK), 'gmres' or 'adaptive' (GMRES with estimator-based stopping)
      character(len=8) :: linear = 'direct'
      !> adaptive stopping: γ_lin, γ_alg and the local criteria instead of the global ones
      real(dp) :: gamma_lin = 0.3_dp, gamma_alg = 0.3_dp
      logical :: local_criteria = .false.
      integer :: max_it = 100
      real(dp) :: tol = 1.0e-10_dp
      logical :: line_search = .false.
      !> GMRES: 'paper' (algebraic ≤ linearization residual) or 'fixed' (gmres%rtol)
      character(len=8) :: forcing = 'paper'
      character(len=8) :: precond = 'ilu0'
      type(gmres_options_t) :: gmres
      logical :: verbose = .true.
   end type newton_options_t

   type :: newton_result_t
      !> the iterate [X1; X2; X3] at interior vertices
      real(dp), allocatable :: x(:)
      integer :: iterations = 0
      integer :: linear_iterations = 0
      logical :: converged = .false.
      character(len=:), allocatable :: status
      type(history_t) :: history
   end type newton_result_t

   !> Extension point: fill the error/estimator columns of a history row for iterate x.
   type, abstract :: newton_observer_t
   contains
      procedure(observe_interface), deferred :: observe
   end type newton_observer_t

   abstract interface
      subroutine observe_interface(self, x, row)
         import :: newton_observer_t, history_row_t, dp
         class(newton_observer_t), intent(inout) :: self
         real(dp), intent(in) :: x(:)
         type(history_row_t), intent(inout) :: row
      end subroutine observe_interface
   end interface

   !> What the linearization needs, shared by the Newton loop and the GMRES observer.
   type :: linearization_t
      type(newton_system_t) :: sys
      character(len=8) :: cfun = 'min'
      real(dp) :: f_norm = 1.0_dp
      !> 1/(|ω_a|/3) for both membrane blocks, to measure their rows in load units
      real(dp), allocatable :: inv_mass(:)
   contains
      procedure :: residual
      procedure :: merit
   end type linearization_t

   !> Records a history row every ν GMRES iterations and applies the paper's forcing.
   type, extends(gmres_observer_t) :: step_observer_t
      type(linearization_t), pointer :: lin => null()
      type(history_t), pointer :: history => null()
      class(newton_observer_t), pointer :: user => null()
      logical :: paper_forcing = .true., adaptive = .false., local_criteria = .false.
      real(dp) :: gamma_alg = 0.3_dp
      integer :: newton_it = 0, gmres_before = 0
      real(dp) :: b_norm = 1.0_dp, t0 = 0.0_dp
   contains
      procedure :: observe => observe_gmres
   end type step_observer_t

contains

   subroutine newton_solve(p, options, x0, result, err, observer)
      type(discrete_problem_t), intent(in) :: p
      type(newton_options_t), intent(in) :: options
      real(dp), intent(in) :: x0(:)
      type(newton_result_t), target, intent(out) :: result
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), intent(inout), target, optional :: observer

      type(linearization_t), target :: lin
      type(linear_step_t) :: solver
      type(step_observer_t) :: inner
      type(history_row_t) :: row
      real(dp), allocatable :: x(:), x_new(:), b(:), c(:), da(:), db(:), ax(:)
      logical, allocatable :: active(:), previous(:)
      integer(i8), allocatable :: seen_hash(:)
      integer, allocatable :: seen_count(:)
      integer(ip) :: n
      integer :: k, j
      real(dp) :: t0, step
      integer :: gmres_failures, last_damped
      character(len=16) :: count_text
      character(len=:), allocatable :: gmres_reason
      type(history_row_t) :: last_inner
      logical :: reuse_inner
      !> the last residuals: the line search compares with their maximum (non-monotone)
      real(dp) :: recent(5)
      character(len=:), allocatable :: why
      logical :: adaptive

      n = p%n
      adaptive = options%linear == 'adaptive'
      if (adaptive .and. .not. present(observer)) then
         call make_error(err, exit_io, 'newton', 'the adaptive method needs an estimator observer')
         return
      end if
      call lin%sys%init(p)
      lin%cfun = options%cfun
      lin%inv_mass = [1/p%mass, 1/p%mass]
      lin%f_norm = norm2(lin%sys%f)
      if (.not. lin%f_norm > 0.0_dp) lin%f_norm = 1.0_dp
      call solver%init(merge('gmres   ', options%linear, adaptive), options%precond, options%gmres, err)
      if (allocated(err)) return
      allocate (c(n), da(n), db(n), b(3*n), ax(3*n), active(n), previous(n))
      allocate (seen_hash(0:options%max_it), seen_count(0:options%max_it))
      x = x0
      t0 = wall_time()
      ! before the first linearization no vertex is in contact
      previous = .false.
      recent = 0.0_dp
      gmres_failures = 0
      last_damped = 0

      row = not_computed()
      reuse_inner = .false.
      call lin%residual(x, row%lin_residual, c, da, db)
      call record(0, row)
      previous = active
      if (row%lin_residual <= options%tol) why = 'converged'

      inner%lin => lin
      inner%history => result%history
      if (present(observer)) inner%user => observer
      inner%paper_forcing = options%forcing == 'paper' .and. .not. adaptive
      inner%adaptive = adaptive
      inner%local_criteria = options%local_criteria
      inner%gamma_alg = options%gamma_alg
      inner%t0 = t0

      k = 0
      do while (.not. allocated(why))
         if (k == options%max_it) then
            why = 'not converged: iteration limit newton.max_it reached'
            exit
         end if
         k = k + 1
         ! B = [F; J_C X − C(X)] with the Jacobian of the previous iterate
         b(1:2*n) = lin%sys%f
         b(2*n + 1:) = da*(x(1:n) - x(n + 1:2*n)) + db*x(2*n + 1:) - c
         call lin%sys%set_jacobian(da, db)
         x_new = x
         if (options%linear /= 'direct') then
            inner%newton_it = k
            inner%gmres_before = result%linear_iterations
            inner%b_norm = max(norm2(b), tiny(1.0_dp))
            call solver%solve(lin%sys%a, b, x_new, err, observer=inner)
            if (allocated(err)) return
            result%linear_iterations = result%linear_iterations + solver%monitor%iterations
            if (.not. all(ieee_is_finite(x_new))) then
               why = 'not converged: GMRES broke down ('//solver%monitor%reason//') with a non-finite iterate'
               exit
            end if
            if (.not. solver%monitor%converged .and. solver%monitor%reason /= 'stopped by observer') then
               gmres_failures = gmres_failures + 1
               gmres_reason = solver%monitor%reason
            end if
         else
            call solver%solve(lin%sys%a, b, x_new, err)
            if (allocated(err)) return
         end if
         call lin%sys%a%matvec(x_new, ax)
         row = not_computed()
         row%alg_residual = norm2(b - ax)/max(norm2(b), tiny(1.0_dp))
         step = 1.0_dp
         if (options%line_search) then
            recent(modulo(k - 1, size(recent)) + 1) = lin%merit(x)
            call backtrack(x, x_new, maxval(recent), step)
         end if
         x = x + step*(x_new - x)
         if (step < 1.0_dp) last_damped = k
         call lin%residual(x, row%lin_residual, c, da, db)
         row%step = step
         ! GMRES stopped by the forcing at a full step: its last inner row saw this very iterate,
         ! so the Newton row replaces it and reuses what the observer computed there
         reuse_inner = .false.
         if (result%history%n > 0 .and. step == 1.0_dp) then
            associate (r => result%history%rows(result%history%n))
               reuse_inner = r%inner .and. r%gmres_it == result%linear_iterations
               if (reuse_inner) last_inner = r
            end associate
         end if
         if (reuse_inner) result%history%n = result%history%n - 1
         call record(k, row)
         if (row%lin_residual <= options%tol) then
            why = 'converged'
         else if (adaptive) then
            if (lin_criterion(row, options)) why = 'converged'
         else if (options%linear == 'direct' .and. step == 1.0_dp) then
            ! exact full steps of Newton-min: a repeated active set cannot make progress
            if (row%active_changed == 0 .and. options%cfun == 'min') then
               why = 'not converged: stagnation (active set unchanged, residual above newton.tol: '// &
                     'round-off floor reached)'
            else if (options%cfun == 'min') then
               ! a damped step breaks the Newton-min map: compare only since the last one
               do j = last_damped, k - 2
                  if (seen_hash(j) == seen_hash(k) .and. seen_count(j) == seen_count(k)) then
                     why = 'not converged: stagnation (Newton-min cycles between active sets)'
                     exit
                  end if
               end do
            end if
         end if
         previous = active
      end do

      result%x = x
      result%iterations = k
      result%converged = why == 'converged'
      if (gmres_failures > 0 .and. why /= 'converged') then
         write (count_text, '(i0)') gmres_failures
         why = why//' ('//trim(count_text)//' GMRES solves ended by '''//gmres_reason//''')'
      end if
      result%status = why

   contains

      !> Halve the step until the merit falls below the largest of its last five values
      !> (Armijo, σ = 1e-4, with the non-monotone reference of Grippo, Lampariello and Lucidi):
      !> semismooth Newton's residual may rise for a step or two on its way, and a monotone
      !> rule then forces tiny steps (measured: Fischer–Burmeister took 33 steps instead of 10,
      !> or failed). A step that never satisfies the test is taken in full, so Newton-min keeps
      !> its finite active-set termination.
      subroutine backtrack(x, x_new, res0, alpha)
         real(dp), intent(in) :: x(:), x_new(:), res0
         real(dp), intent(out) :: alpha

         integer :: halvings

         alpha = 1.0_dp
         do halvings = 0, 30
            if (lin%merit(x + alpha*(x_new - x)) <= (1 - 1.0e-4_dp*alpha)*res0) return
            alpha = alpha/2
         end do
         alpha = 1.0_dp
      end subroutine backtrack

      subroutine record(k, row)
         integer, intent(in) :: k
         type(history_row_t), intent(inout) :: row

         ! contact where u1 − u2 ≤ λ: for Newton-min exactly the vertices with the a-row
         active = x(1:n) - x(n + 1:2*n) <= x(2*n + 1:)
         row%newton_it = k
         row%gmres_it = result%linear_iterations
         row%active = count(active)
         row%active_changed = count(active .neqv. previous)
         seen_hash(k) = hash_set(active)
         seen_count(k) = row%active
         if (reuse_inner) then
            call row%take_observations(last_inner)
         else if (present(observer)) then
            call observer%observe(x, row)
         end if
         row%wall_time = wall_time() - t0
         call result%history%append(row)
         if (options%verbose) call progress_line(row)
      end subroutine record
   end subroutine newton_solve

   !> ‖[F − E X; −C(X)]‖/‖[F; 0]‖ and the C-function with its Jacobian at x.
   subroutine residual(self, x, rel, c, da, db)
      class(linearization_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: rel
      real(dp), intent(out) :: c(:), da(:), db(:)

      real(dp), allocatable :: ex(:)
      integer(ip) :: n

      n = self%sys%n
      call cfun_eval(self%cfun, x(1:n) - x(n + 1:2*n), x(2*n + 1:), c, da, db)
      allocate (ex(2*n))
      call self%sys%apply_e(x, ex)
      rel = sqrt(sum((self%sys%f - ex)**2) + sum(c**2))/self%f_norm
   end subroutine residual

   !> The line search's merit ‖[D⁻¹(F − E X); C(X)]‖: the membrane rows measured as strong
   !> residuals (load units, independent of h) rather than h²-weighted, so that they weigh like
   !> the C-function rows. With the weak rows, (g, 0, 0) looks almost solved (C(g, 0) = 0 and
   !> F ~ h²) and every useful first step looks like a huge increase.
   real(dp) function merit(self, x)
      class(linearization_t), intent(in) :: self
      real(dp), intent(in) :: x(:)

      real(dp), allocatable :: ex(:), c(:), da(:), db(:)
      integer(ip) :: n

      n = self%sys%n
      allocate (ex(2*n), c(n), da(n), db(n))
      call cfun_eval(self%cfun, x(1:n) - x(n + 1:2*n), x(2*n + 1:), c, da, db)
      call self%sys%apply_e(x, ex)
      merit = sqrt(sum((self%inv_mass*(self%sys%f - ex))**2) + sum(c**2))
   end function merit

   !> Every ν GMRES iterations: record the iterate's residuals and, with the paper's forcing,
   !> stop GMRES once ‖R_alg‖/‖B‖ ≤ ‖R_lin(x)‖/‖[F;0]‖.
   subroutine observe_gmres(self, iteration, x, residual_norm, stop)
      class(step_observer_t), intent(inout) :: self
      integer, intent(in) :: iteration
      real(dp), intent(in) :: x(:)
      real(dp), intent(in) :: residual_norm
      logical, intent(out) :: stop

      type(history_row_t) :: row
      real(dp), allocatable :: c(:), da(:), db(:)
      integer(ip) :: n

      n = self%lin%sys%n
      allocate (c(n), da(n), db(n))
      row = not_computed()
      call self%lin%residual(x, row%lin_residual, c, da, db)
      row%alg_residual = residual_norm/self%b_norm
      row%newton_it = self%newton_it
      row%gmres_it = self%gmres_before + iteration
      row%active = count(x(1:n) - x(n + 1:2*n) <= x(2*n + 1:))
      row%inner = .true.
      row%step = ieee_value(1.0_dp, ieee_quiet_nan)
      row%active_changed = -1
      if (associated(self%user)) call self%user%observe(x, row)
      row%wall_time = wall_time() - self%t0
      call self%history%append(row)
      ! For Newton-min, once GMRES's iterate has the Jacobian's contact set, B − A x and R_lin(x)
      ! are the same vector computed two ways: the slack keeps round-off from deciding the tie.
      if (self%adaptive) then
         stop = alg_criterion(row, self%gamma_alg, self%local_criteria)
      else
         stop = self%paper_forcing .and. row%alg_residual <= row%lin_residual*(1 + 1.0e-8_dp)
      end if
   end subroutine observe_gmres

   !> The paper's GMRES stop (63a), η_alg ≤ γ_alg max(η_disc, η_lin), or its local form (64a).
   pure logical function alg_criterion(row, gamma_alg, local) result(ok)
      type(history_row_t), intent(in) :: row
      real(dp), intent(in) :: gamma_alg
      logical, intent(in) :: local

      if (local) then
         ok = row%local_alg_ok
      else
         ok = row%eta_alg <= gamma_alg*max(row%eta_disc, row%eta_lin)
      end if
   end function alg_criterion

   !> The paper's Newton stop (63b), η_lin ≤ γ_lin η_disc, or its local form (64b).
   pure logical function lin_criterion(row, options) result(ok)
      type(history_row_t), intent(in) :: row
      type(newton_options_t), intent(in) :: options

      if (options%local_criteria) then
         ok = row%local_lin_ok
      else
         ok = row%eta_lin <= options%gamma_lin*row%eta_disc
      end if
   end function lin_criterion

   subroutine progress_line(row)
      type(history_row_t), intent(in) :: row

      character(len=96) :: err_text

      err_text = ''
      if (.not. ieee_is_nan(row%eta_total)) write (err_text, '("  eta ",es9.3," (disc ",es9.3,", lin ",es9.3, &
           &", alg ",es9.3,")")') row%eta_total, row%eta_disc, row%eta_lin, row%eta_alg
      if (.not. ieee_is_nan(row%energy_error)) write (err_text, '(a,"  error ",es9.3)') trim(err_text), row%energy_error
      write (output_unit, '("newton ",i4,"  gmres ",i6,"  contact ",i8," (changed ",i7,")  lin-res ",es9.3, &
           &"  alg-res ",es9.3,"  step ",f5.3,a,"  ",f9.2," s")') row%newton_it, row%gmres_it, row%active, &
         row%active_changed, row%lin_residual, row%alg_residual, row%step, trim(err_text), row%wall_time
      flush (output_unit)
   end subroutine progress_line

   !> Hash of the active set (two polynomial hashes modulo primes below 2**31, so no product
   !> overflows 64 bits), to recognise a set seen before.
   pure integer(i8) function hash_set(active) result(h)
      logical, intent(in) :: active(:)

      integer(i8), parameter :: p1 = 2147483647_i8, p2 = 2147483629_i8
      integer(i8) :: h1, h2
      integer(ip) :: i

      h1 = 0
      h2 = 0
      do i = 1, size(active, kind=ip)
         if (active(i)) then
            h1 = mod(h1*1000003_i8 + i, p1)
            h2 = mod(h2*999983_i8 + i, p2)
         end if
      end do
      h = h1*p2 + h2
   end function hash_set
end module twomem_newton_solver
