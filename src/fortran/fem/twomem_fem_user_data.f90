!> Loads the user brings: each of f1, f2 is a number, a formula of x, y, r
!> (`twomem_input_formula`) or P1 data, nodal values on a triangulation (the coarse or the finest
!> mesh, from a file). Everything that integrates loads sees them only through `problem_data_t`
!> (`load`, `loads_at`), i.e. as functions of position: the assembly, the estimators' load
!> moments and data oscillation. P1 data are therefore evaluated by locating the point in their
!> triangulation, through a uniform grid of buckets of triangles. A formula that is not finite
!> somewhere returns NaN there (quietly: no trap); `explain_load` then says why, and the
!> discrete problem turns that into an input error naming the point.
module twomem_fem_user_data
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_input_formula, only: formula_t, formula_status_text, status_ok
   use twomem_input_formula_parser, only: parse_formula
   use twomem_fem_problem, only: problem_data_t
   use twomem_base_text, only: int_text
   implicit none
   private

   public :: user_data_t, new_user_data, source_constant, source_formula, source_nodal

   integer, parameter :: source_constant = 1, source_formula = 2, source_nodal = 3

   !> P1 data on a triangulation with a bucket grid: cell (i, j) lists, in
   !> cell_triangles(cell_ptr(c):cell_ptr(c+1)-1), the triangles whose bounding box meets it.
   type :: nodal_data_t
      real(dp), allocatable :: vertices(:, :), values(:, :)
      integer(ip), allocatable :: triangles(:, :)
      real(dp) :: lower(2) = 0.0_dp, cell(2) = 1.0_dp
      integer :: nx = 0, ny = 0
      integer(ip), allocatable :: cell_ptr(:), cell_triangles(:)
   end type nodal_data_t

   type, extends(problem_data_t) :: user_data_t
      integer :: kind(2) = source_constant
      real(dp) :: value(2) = 0.0_dp
      type(formula_t) :: formula(2)
      type(nodal_data_t) :: nodal
   contains
      procedure :: load => user_load
      procedure :: loads_at => user_loads_at
      procedure :: explain_load => user_explain_load
      procedure :: set_nodal
   end type user_data_t

contains

   !> Loads from numbers (`f`) or, where `formulas(α)` is not blank, from formulas; nodal
   !> sources are added afterwards by `set_nodal`.
   subroutine new_user_data(mu1, mu2, g, f, formulas, data, err)
      real(dp), intent(in) :: mu1, mu2, g, f(2)
      character(len=*), intent(in) :: formulas(2)
      type(user_data_t), intent(out) :: data
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: why
      integer :: alpha, where

      data%name = 'user'
      data%mu1 = mu1
      data%mu2 = mu2
      data%g = g
      data%value = f
      do alpha = 1, 2
         if (len_trim(formulas(alpha)) == 0) cycle
         call parse_formula(trim(formulas(alpha)), data%formula(alpha), where, why)
         if (allocated(why)) then
            call make_error(err, exit_bad_input, 'problem.f'//achar(48 + alpha), 'column '// &
                            int_text(where)//': '//why)
            return
         end if
         data%kind(alpha) = source_formula
      end do
   end subroutine new_user_data

   !> Load α (where use(α)) is the P1 function with nodal values values(:, α) on the
   !> triangulation (vertices, triangles). Both nodal loads share one triangulation.
   subroutine set_nodal(self, vertices, triangles, values, use)
      class(user_data_t), intent(inout) :: self
      real(dp), intent(in) :: vertices(:, :), values(:, :)
      integer(ip), intent(in) :: triangles(:, :)
      logical, intent(in) :: use(2)

      integer(ip) :: t, c, nt
      integer :: i, j, i0, i1, j0, j1
      integer(ip), allocatable :: fill(:)
      real(dp) :: upper(2), area

      where (use) self%kind = source_nodal
      associate (d => self%nodal)
         d%vertices = vertices
         d%triangles = triangles
         d%values = values
         nt = size(triangles, 2, kind=ip)
         d%lower = minval(vertices, dim=2)
         upper = maxval(vertices, dim=2)
         ! about two triangles per cell
         area = max(product(upper - d%lower), tiny(1.0_dp))
         d%nx = max(1, min(4096, nint(sqrt(real(nt, dp)/2*(upper(1) - d%lower(1))**2/area))))
         d%ny = max(1, min(4096, nint(real(nt, dp)/2/d%nx)))
         d%cell = max((upper - d%lower)/[d%nx, d%ny], tiny(1.0_dp))
         allocate (d%cell_ptr(d%nx*d%ny + 1))
         d%cell_ptr = 0
         do t = 1, nt
            call cell_range(d, t, i0, i1, j0, j1)
            do j = j0, j1
               do i = i0, i1
                  c = cell_index(d, i, j)
                  d%cell_ptr(c + 1) = d%cell_ptr(c + 1) + 1
               end do
            end do
         end do
         d%cell_ptr(1) = 1
         do c = 1, d%nx*d%ny
            d%cell_ptr(c + 1) = d%cell_ptr(c + 1) + d%cell_ptr(c)
         end do
         allocate (d%cell_triangles(d%cell_ptr(d%nx*d%ny + 1) - 1), fill(d%nx*d%ny))
         fill = d%cell_ptr(1:d%nx*d%ny)
         do t = 1, nt
            call cell_range(d, t, i0, i1, j0, j1)
            do j = j0, j1
               do i = i0, i1
                  c = cell_index(d, i, j)
                  d%cell_triangles(fill(c)) = t
                  fill(c) = fill(c) + 1
               end do
            end do
         end do
      end associate
   end subroutine set_nodal

   pure subroutine cell_range(d, t, i0, i1, j0, j1)
      type(nodal_data_t), intent(in) :: d
      integer(ip), intent(in) :: t
      integer, intent(out) :: i0, i1, j0, j1

      real(dp) :: lo(2), hi(2)

      lo = minval(d%vertices(:, d%triangles(:, t)), dim=2)
      hi = maxval(d%vertices(:, d%triangles(:, t)), dim=2)
      call cell_of(d, lo, i0, j0)
      call cell_of(d, hi, i1, j1)
   end subroutine cell_range

   pure subroutine cell_of(d, x, i, j)
      type(nodal_data_t), intent(in) :: d
      real(dp), intent(in) :: x(2)
      integer, intent(out) :: i, j

      i = min(d%nx, max(1, int((x(1) - d%lower(1))/d%cell(1)) + 1))
      j = min(d%ny, max(1, int((x(2) - d%lower(2))/d%cell(2)) + 1))
   end subroutine cell_of

   pure integer(ip) function cell_index(d, i, j)
      type(nodal_data_t), intent(in) :: d
      integer, intent(in) :: i, j

      cell_index = int(j - 1, ip)*d%nx + i
   end function cell_index

   !> The P1 data at x: the triangle of x's cell that contains it (the one where x is least
   !> outside, for points on edges or a rounding error away from the triangulation).
   pure subroutine nodal_values(d, x, v)
      type(nodal_data_t), intent(in) :: d
      real(dp), intent(in) :: x(2)
      real(dp), intent(out) :: v(2)

      integer(ip) :: m, t, best
      integer :: i, j
      real(dp) :: b(3), best_b(3), p(2, 3), det, worst

      call cell_of(d, x, i, j)
      best = 0
      worst = -huge(1.0_dp)
      best_b = 0.0_dp
      do m = d%cell_ptr(cell_index(d, i, j)), d%cell_ptr(cell_index(d, i, j) + 1) - 1
         t = d%cell_triangles(m)
         p = d%vertices(:, d%triangles(:, t))
         det = (p(1, 2) - p(1, 1))*(p(2, 3) - p(2, 1)) - (p(1, 3) - p(1, 1))*(p(2, 2) - p(2, 1))
         b(2) = ((x(1) - p(1, 1))*(p(2, 3) - p(2, 1)) - (p(1, 3) - p(1, 1))*(x(2) - p(2, 1)))/det
         b(3) = ((p(1, 2) - p(1, 1))*(x(2) - p(2, 1)) - (x(1) - p(1, 1))*(p(2, 2) - p(2, 1)))/det
         b(1) = 1 - b(2) - b(3)
         if (minval(b) > worst) then
            worst = minval(b)
            best = t
            best_b = b
            if (worst >= 0) exit
         end if
      end do
      if (best == 0) then
         ! outside the triangulation's cells: no data (the solver never asks there)
         v = 0.0_dp
         return
      end if
      do i = 1, 2
         v(i) = dot_product(best_b, d%values(d%triangles(:, best), i))
      end do
   end subroutine nodal_values

   pure real(dp) function user_load(self, alpha, x)
      class(user_data_t), intent(in) :: self
      integer, intent(in) :: alpha
      real(dp), intent(in) :: x(2)

      real(dp) :: v(2)
      integer :: status

      select case (self%kind(alpha))
      case (source_formula)
         call self%formula(alpha)%evaluate_point(x, user_load, status)
         if (status /= status_ok) user_load = ieee_value(1.0_dp, ieee_quiet_nan)
      case (source_nodal)
         call nodal_values(self%nodal, x, v)
         user_load = v(alpha)
      case default
         user_load = self%value(alpha)
      end select
   end function user_load

   !> Both loads at a batch of points; a formula evaluates the whole batch at once.
   pure subroutine user_loads_at(self, x, f)
      class(user_data_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: f(:, :)

      real(dp) :: v(2)
      integer :: alpha, k, status, bad

      do alpha = 1, 2
         select case (self%kind(alpha))
         case (source_formula)
            call self%formula(alpha)%evaluate(x, f(alpha, :), status, bad)
            if (status /= status_ok) f(alpha, :) = ieee_value(1.0_dp, ieee_quiet_nan)
         case (source_nodal)
            do k = 1, size(x, 2)
               call nodal_values(self%nodal, x(:, k), v)
               f(alpha, k) = v(alpha)
            end do
         case default
            f(alpha, :) = self%value(alpha)
         end select
      end do
   end subroutine user_loads_at

   !> Why load α is not finite at x ('' if it is).
   function user_explain_load(self, alpha, x) result(why)
      class(user_data_t), intent(in) :: self
      integer, intent(in) :: alpha
      real(dp), intent(in) :: x(2)
      character(len=:), allocatable :: why

      real(dp) :: v
      integer :: status

      why = ''
      if (self%kind(alpha) /= source_formula) return
      call self%formula(alpha)%evaluate_point(x, v, status)
      if (status /= status_ok) why = "formula '"//self%formula(alpha)%text//"': "//formula_status_text(status)
   end function user_explain_load
end module twomem_fem_user_data
