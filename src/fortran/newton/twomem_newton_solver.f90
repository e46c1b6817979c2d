!> The semismooth Newton driver. Each step linearizes the C-function at the current iterate,
!> solves the Newton system and checks the paper's stopping test ‖R_lin‖/‖[F;0]‖ ≤ tol with
!> R_lin = [F − E X; −C(X)] (DESIGN.md §2). It stops with a reason when the step limit is hit, when
!> Newton-min revisits an active set (cycling) or when the active set stops changing with the
!> residual still above the tolerance (round-off floor). What the caller wants to know about an
!> iterate beyond residuals (exact errors, estimators) it computes in an observer.
module twomem_newton_solver
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_is_nan
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_umfpack, only: umfpack_solver_t
   use twomem_newton_cfun, only: cfun_eval
   use twomem_newton_system, only: newton_system_t
   use twomem_newton_history, only: history_t, history_row_t, not_computed
   implicit none
   private

   public :: newton_options_t, newton_result_t, newton_observer_t, newton_solve

   type :: newton_options_t
      character(len=8) :: cfun = 'min'
      character(len=8) :: linear = 'direct'
      integer :: max_it = 100
      real(dp) :: tol = 1.0e-10_dp
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

contains

   subroutine newton_solve(p, options, x0, result, err, observer)
      type(discrete_problem_t), intent(in) :: p
      type(newton_options_t), intent(in) :: options
      real(dp), intent(in) :: x0(:)
      type(newton_result_t), intent(out) :: result
      type(error_t), allocatable, intent(out) :: err
      class(newton_observer_t), intent(inout), optional :: observer

      type(newton_system_t) :: sys
      type(umfpack_solver_t) :: direct
      type(history_row_t) :: row
      real(dp), allocatable :: x(:), b(:), c(:), da(:), db(:), ax(:)
      logical, allocatable :: active(:), previous(:)
      integer(i8), allocatable :: seen_hash(:)
      integer, allocatable :: seen_count(:)
      integer(ip) :: n
      integer :: k, j
      real(dp) :: f_norm, t0
      character(len=:), allocatable :: why

      n = p%n
      call sys%init(p)
      f_norm = norm2(sys%f)
      if (.not. f_norm > 0.0_dp) f_norm = 1.0_dp
      allocate (c(n), da(n), db(n), b(3*n), ax(3*n), active(n), previous(n))
      allocate (seen_hash(0:options%max_it), seen_count(0:options%max_it))
      x = x0
      t0 = wall_seconds()
      ! before the first linearization no vertex is in contact
      previous = .false.

      call linearize(x, row)
      row%alg_residual = 0.0_dp
      call record(0, row)
      previous = active
      if (row%lin_residual <= options%tol) why = 'converged'

      k = 0
      do while (.not. allocated(why))
         if (k == options%max_it) then
            why = 'not converged: iteration limit newton.max_it reached'
            exit
         end if
         k = k + 1
         ! B = [F; J_C X − C(X)] with the Jacobian of the previous iterate
         b(1:2*n) = sys%f
         b(2*n + 1:) = da*(x(1:n) - x(n + 1:2*n)) + db*x(2*n + 1:) - c
         call sys%set_jacobian(da, db)
         call direct%factor(sys%a, err)
         if (allocated(err)) return
         call direct%solve(sys%a, b, x, err)
         if (allocated(err)) return
         call linearize(x, row)
         call sys%a%matvec(x, ax)
         row%alg_residual = norm2(b - ax)/max(norm2(b), tiny(1.0_dp))
         call record(k, row)
         if (row%lin_residual <= options%tol) then
            why = 'converged'
         else if (row%active_changed == 0) then
            why = 'not converged: stagnation (active set unchanged, residual above newton.tol: '// &
                  'round-off floor reached)'
         else
            do j = 0, k - 2
               if (seen_hash(j) == seen_hash(k) .and. seen_count(j) == seen_count(k)) then
                  why = 'not converged: stagnation (Newton-min cycles between active sets)'
                  exit
               end if
            end do
         end if
         previous = active
      end do

      result%x = x
      result%iterations = k
      result%converged = why == 'converged'
      result%status = why

   contains

      !> C-function, its Jacobian, the active set and the linearization residual at x.
      subroutine linearize(x, row)
         real(dp), intent(in) :: x(:)
         type(history_row_t), intent(out) :: row

         real(dp), allocatable :: ex(:)

         row = not_computed()
         call cfun_eval(options%cfun, x(1:n) - x(n + 1:2*n), x(2*n + 1:), c, da, db)
         active = da > db
         allocate (ex(2*n))
         call sys%apply_e(x, ex)
         row%lin_residual = sqrt(sum((sys%f - ex)**2) + sum(c**2))/f_norm
      end subroutine linearize

      subroutine record(k, row)
         integer, intent(in) :: k
         type(history_row_t), intent(inout) :: row

         row%newton_it = k
         row%gmres_it = 0
         row%active = count(active)
         row%active_changed = count(active .neqv. previous)
         seen_hash(k) = hash_set(active)
         seen_count(k) = row%active
         if (present(observer)) call observer%observe(x, row)
         row%wall_time = wall_seconds() - t0
         call result%history%append(row)
         if (options%verbose) call progress_line(row)
      end subroutine record
   end subroutine newton_solve

   subroutine progress_line(row)
      type(history_row_t), intent(in) :: row

      character(len=32) :: err_text

      if (.not. ieee_is_nan(row%energy_error)) then
         write (err_text, '("  error ",es9.3)') row%energy_error
      else
         err_text = ''
      end if
      write (output_unit, '("newton ",i4,"  contact ",i8," (changed ",i7,")  lin-res ",es9.3, &
           &"  alg-res ",es9.3,a,"  ",f9.2," s")') row%newton_it, row%active, row%active_changed, &
         row%lin_residual, row%alg_residual, trim(err_text), row%wall_time
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

   real(dp) function wall_seconds()
      integer(i8) :: count, rate

      call system_clock(count, rate)
      wall_seconds = real(count, dp)/real(rate, dp)
   end function wall_seconds
end module twomem_newton_solver
