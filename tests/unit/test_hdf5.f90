!> Tests of the HDF5 layer and the XDMF sidecar: exact round trips of datasets and attributes,
!> the shape convention h5py and XDMF rely on, and I/O failures that come back as errors.
module test_hdf5
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: exit_io
   use twomem_base_system, only: make_directories, file_exists, remove_file, process_id
   use twomem_hdf5_file, only: h5_file_t
   use twomem_io_xdmf, only: write_xdmf
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   use twomem_base_text, only: int_text
   implicit none
   private

   public :: collect_hdf5

contains

   subroutine collect_hdf5(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('dataset_round_trip', test_datasets), &
               new_unittest('attribute_round_trip', test_attributes), &
               new_unittest('shape_convention', test_shape), &
               new_unittest('empty_and_rewritten', test_empty_and_rewrite), &
               new_unittest('non_contiguous_sections', test_sections), &
               new_unittest('missing_directory', test_missing_directory), &
               new_unittest('path_under_a_file', test_under_file), &
               new_unittest('read_errors', test_read_errors), &
               new_unittest('xdmf_sidecar', test_xdmf)]
   end subroutine collect_hdf5

   !> A scratch directory of this suite, created on demand.
   function scratch(name, err) result(path)
      character(len=*), intent(in) :: name
      type(error_t), allocatable, intent(out) :: err
      character(len=:), allocatable :: path

      character(len=1024) :: root
      integer :: length, status

      path = ''
      call get_environment_variable('TWOMEM_TEST_TMP', root, length, status)
      call check(err, status == 0 .and. length > 0, 'TWOMEM_TEST_TMP is not set (run through ctest)')
      if (allocated(err)) return
      call make_directories(root(1:length)//'/hdf5', err)
      path = root(1:length)//'/hdf5/'//name
   end function scratch

   subroutine test_datasets(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      character(len=:), allocatable :: path
      real(dp), allocatable :: r1(:), r2(:, :)
      integer(ip), allocatable :: i1(:), i2(:, :)
      real(dp) :: x1(7), x2(3, 4)
      integer(ip) :: j1(5), j2(3, 2)
      integer :: k

      ! values that a lossy conversion would change
      x1 = [(1.0_dp/real(k, dp), k=1, 6), -huge(1.0_dp)]
      x2 = reshape([(sqrt(real(k, dp)), k=1, 12)], [3, 4])
      j1 = [0_ip, -1_ip, huge(1_ip), -huge(1_ip), 42_ip]
      j2 = reshape([1_ip, 2_ip, 3_ip, 4_ip, 5_ip, 6_ip], [3, 2])
      path = scratch('datasets.h5', err)
      if (allocated(err)) return
      call file%create(path, err)
      if (allocated(err)) return
      call file%write_real('/a/r1', x1, err)
      if (.not. allocated(err)) call file%write_real('/a/b/r2', x2, err)
      if (.not. allocated(err)) call file%write_int('/i1', j1, err)
      if (.not. allocated(err)) call file%write_int('/c/i2', j2, err)
      if (.not. allocated(err)) call file%close(err)
      if (allocated(err)) return

      call file%open_read(path, err)
      if (allocated(err)) return
      call check(err, file%has('/a') .and. file%has('/a/b') .and. file%has('/a/b/r2'), 'groups created')
      call check(err, .not. file%has('/nothing') .and. .not. file%has('/nothing/deeper'), 'has() of missing')
      if (allocated(err)) return
      call file%read_real('/a/r1', r1, err)
      if (.not. allocated(err)) call file%read_real('/a/b/r2', r2, err)
      if (.not. allocated(err)) call file%read_int('/i1', i1, err)
      if (.not. allocated(err)) call file%read_int('/c/i2', i2, err)
      if (allocated(err)) return
      call check(err, all(shape(r1) == shape(x1)) .and. all(r1 == x1), 'real 1-D equal')
      call check(err, all(shape(r2) == shape(x2)) .and. all(r2 == x2), 'real 2-D equal')
      call check(err, all(shape(i1) == shape(j1)) .and. all(i1 == j1), 'int 1-D equal')
      call check(err, all(shape(i2) == shape(j2)) .and. all(i2 == j2), 'int 2-D equal')
      if (allocated(err)) return
      call file%close(err)
   end subroutine test_datasets

   subroutine test_attributes(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      character(len=:), allocatable :: path, text, got_text, short
      real(dp) :: got_real
      integer :: got_int, k

      ! a namelist-sized text with line breaks and quotes
      allocate (character(len=5000) :: text)
      do k = 1, len(text)
         text(k:k) = achar(32 + mod(7*k, 95))
         if (mod(k, 71) == 0) text(k:k) = achar(10)
      end do
      path = scratch('attributes.h5', err)
      if (allocated(err)) return
      call file%create(path, err)
      if (allocated(err)) return
      call file%write_attr('/', 'input', text, err)
      if (.not. allocated(err)) call file%write_attr('/', 'version', 'v0.1 ', err)
      if (.not. allocated(err)) call file%write_attr('/', 'empty', '', err)
      if (.not. allocated(err)) call file%write_attr('/summary', 'eta_total', 1.0_dp/3.0_dp, err)
      if (.not. allocated(err)) call file%write_attr('/summary', 'nv', -123456, err)
      if (.not. allocated(err)) call file%write_attr('/summary', 'nv', 123456, err)
      if (.not. allocated(err)) call file%write_real('/estimators/eta', [1.0_dp, 2.0_dp], err)
      if (.not. allocated(err)) call file%write_attr('/estimators/eta', 'total', sqrt(5.0_dp), err)
      if (.not. allocated(err)) call file%close(err)
      if (allocated(err)) return

      call file%open_read(path, err)
      if (allocated(err)) return
      call check(err, file%has_attr('/', 'input') .and. file%has_attr('/summary', 'nv'), 'has_attr')
      call check(err, .not. file%has_attr('/', 'nv') .and. .not. file%has_attr('/none', 'nv'), &
                 'has_attr of missing')
      if (allocated(err)) return
      call file%read_attr('/', 'input', got_text, err)
      if (allocated(err)) return
      call check(err, len(got_text) == 5000, 'long string keeps its length')
      call check(err, got_text == text, 'long string equal')
      call file%read_attr('/', 'version', short, err)
      if (allocated(err)) return
      call check(err, short == 'v0.1 ' .and. len(short) == 5, 'trailing blank kept')
      call file%read_attr('/', 'empty', short, err)
      if (allocated(err)) return
      call check(err, len(short) == 0, 'empty string')
      call file%read_attr('/summary', 'eta_total', got_real, err)
      if (allocated(err)) return
      call check(err, got_real == 1.0_dp/3.0_dp, 'real attribute equal')
      call file%read_attr('/summary', 'nv', got_int, err)
      if (allocated(err)) return
      call check(err, got_int == 123456, 'rewritten int attribute equal')
      call file%read_attr('/estimators/eta', 'total', got_real, err)
      if (allocated(err)) return
      call check(err, got_real == sqrt(5.0_dp), 'attribute on a dataset')
      if (allocated(err)) return
      call file%close(err)
   end subroutine test_attributes

   !> a(2, 5) in Fortran is (5, 2) for HDF5, h5py and XDMF, and comes back as (2, 5).
   subroutine test_shape(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      character(len=:), allocatable :: path
      real(dp), allocatable :: back(:, :)
      integer(i8), allocatable :: dims(:)
      real(dp) :: a(2, 5)
      integer :: k

      a = reshape([(real(k, dp), k=1, 10)], [2, 5])
      path = scratch('shape.h5', err)
      if (allocated(err)) return
      call file%create(path, err)
      if (.not. allocated(err)) call file%write_real('/mesh/vertices', a, err)
      if (.not. allocated(err)) call file%close(err)
      if (.not. allocated(err)) call file%open_read(path, err)
      if (.not. allocated(err)) call file%get_dims('/mesh/vertices', dims, err)
      if (allocated(err)) return
      call check(err, size(dims) == 2, 'rank 2')
      if (allocated(err)) return
      call check(err, dims(1) == 5 .and. dims(2) == 2, 'HDF5 dims (5, 2)')
      call file%read_real('/mesh/vertices', back, err)
      if (allocated(err)) return
      call check(err, size(back, 1) == 2 .and. size(back, 2) == 5, 'read back as (2, 5)')
      call check(err, all(back == a), 'same values')
      if (allocated(err)) return
      call file%close(err)
   end subroutine test_shape

   subroutine test_empty_and_rewrite(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      character(len=:), allocatable :: path
      real(dp), allocatable :: back(:)
      integer(ip), allocatable :: iback(:, :)
      real(dp) :: empty(0)
      integer(ip) :: none(3, 0)

      path = scratch('empty.h5', err)
      if (allocated(err)) return
      call file%create(path, err)
      if (.not. allocated(err)) call file%write_real('/history/eta', empty, err)
      if (.not. allocated(err)) call file%write_int('/mesh/triangles', none, err)
      if (.not. allocated(err)) call file%write_real('/x', [1.0_dp, 2.0_dp, 3.0_dp], err)
      if (.not. allocated(err)) call file%write_real('/x', [4.0_dp], err)
      if (.not. allocated(err)) call file%close(err)
      if (.not. allocated(err)) call file%open_read(path, err)
      if (.not. allocated(err)) call file%read_real('/history/eta', back, err)
      if (allocated(err)) return
      call check(err, size(back) == 0, 'empty dataset')
      call file%read_int('/mesh/triangles', iback, err)
      if (allocated(err)) return
      call check(err, size(iback, 1) == 3 .and. size(iback, 2) == 0, 'empty 2-D dataset')
      call file%read_real('/x', back, err)
      if (allocated(err)) return
      call check(err, size(back) == 1, 'rewritten dataset has its new shape')
      if (allocated(err)) return
      call check(err, back(1) == 4.0_dp, 'rewritten dataset has its new value')
   end subroutine test_empty_and_rewrite

   !> Strided sections and components of derived-type arrays (history rows) are written as
   !> their values, not as the memory they happen to live in.
   subroutine test_sections(err)
      type(error_t), allocatable, intent(out) :: err
      type :: row_t
         integer(ip) :: it
         real(dp) :: eta
      end type row_t
      type(h5_file_t) :: file
      type(row_t) :: rows(4)
      character(len=:), allocatable :: path
      real(dp), allocatable :: back(:), back2(:, :)
      integer(ip), allocatable :: iback(:)
      real(dp) :: a(4, 6)
      integer :: k

      a = reshape([(real(k, dp), k=1, 24)], [4, 6])
      rows = [(row_t(int(10*k, ip), 0.5_dp*k), k=1, 4)]
      path = scratch('sections.h5', err)
      if (allocated(err)) return
      call file%create(path, err)
      if (.not. allocated(err)) call file%write_real('/strided', a(2, 1:5:2), err)
      if (.not. allocated(err)) call file%write_real('/block', a(2:3, 2:6:2), err)
      if (.not. allocated(err)) call file%write_real('/rows/eta', rows(1:3)%eta, err)
      if (.not. allocated(err)) call file%write_int('/rows/it', rows(2:4)%it, err)
      if (.not. allocated(err)) call file%close(err)
      if (.not. allocated(err)) call file%open_read(path, err)
      if (.not. allocated(err)) call file%read_real('/strided', back, err)
      if (allocated(err)) return
      call check(err, size(back) == 3, 'strided size')
      if (allocated(err)) return
      call check(err, all(back == a(2, 1:5:2)), 'strided values')
      call file%read_real('/block', back2, err)
      if (allocated(err)) return
      call check(err, all(shape(back2) == [2, 3]), 'block shape')
      if (allocated(err)) return
      call check(err, all(back2 == a(2:3, 2:6:2)), 'block values')
      call file%read_real('/rows/eta', back, err)
      if (allocated(err)) return
      call check(err, size(back) == 3, 'component size')
      if (allocated(err)) return
      call check(err, all(back == [0.5_dp, 1.0_dp, 1.5_dp]), 'component values')
      call file%read_int('/rows/it', iback, err)
      if (allocated(err)) return
      call check(err, size(iback) == 3, 'int component size')
      if (allocated(err)) return
      call check(err, all(iback == [20, 30, 40]), 'int component values')
   end subroutine test_sections

   subroutine test_missing_directory(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path

      path = scratch('no/such/directory/a.h5', err)
      if (allocated(err)) return
      call file%create(path, got)
      call check(err, allocated(got), 'error returned')
      if (.not. allocated(got)) return
      call check(err, got%code == exit_io, 'I/O error code')
      call check(err, index(got%message, path//': HDF5: ') == 1, 'message starts with the path: '//got%message)
      call check(err, index(got%message, 'No such file or directory') > 0, 'message gives the cause: '//got%message)
      call check(err, index(got%message, new_line('a')) == 0, 'message is one line')
      call check(err, .not. file%is_open(), 'file not open')
      deallocate (got)
      ! using the unopened file is an error too, not a crash
      call file%write_real('/x', [1.0_dp], got)
      call check(err, allocated(got), 'write to unopened file rejected')
   end subroutine test_missing_directory

   !> Root ignores permissions, so a path through a regular file stands in for an unwritable one.
   subroutine test_under_file(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      type(error_t), allocatable :: got
      character(len=:), allocatable :: plain, path
      integer :: unit, ios

      plain = scratch('plain_file', err)
      if (allocated(err)) return
      open (newunit=unit, file=plain, status='replace', action='write', iostat=ios)
      call check(err, ios == 0, 'scratch file created')
      if (allocated(err)) return
      close (unit)
      path = plain//'/a.h5'
      call file%create(path, got)
      call check(err, allocated(got), 'error returned')
      if (.not. allocated(got)) return
      call check(err, got%code == exit_io, 'I/O error code')
      call check(err, index(got%message, path) == 1, 'message names the path: '//got%message)
      call check(err, index(got%message, 'Not a directory') > 0, 'message gives the cause: '//got%message)
   end subroutine test_under_file

   subroutine test_read_errors(err)
      type(error_t), allocatable, intent(out) :: err
      type(h5_file_t) :: file
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path, text
      real(dp), allocatable :: r2(:, :)
      integer(ip), allocatable :: i1(:)
      real(dp) :: x

      path = scratch('read_errors.h5', err)
      if (allocated(err)) return
      call file%create(path, err)
      if (.not. allocated(err)) call file%write_real('/r', [1.0_dp, 2.0_dp], err)
      if (.not. allocated(err)) call file%write_attr('/', 'n', 3, err)
      if (.not. allocated(err)) call file%close(err)
      if (.not. allocated(err)) call file%open_read(path, err)
      if (allocated(err)) return

      call file%read_real('/missing', r2, got)
      call check(err, allocated(got), 'missing dataset')
      if (allocated(got)) call check(err, index(got%message, path//':/missing: HDF5: ') == 1, &
                                     'names file and dataset: '//got%message)
      call file%read_real('/r', r2, got)
      call check(err, allocated(got), 'rank mismatch')
      if (allocated(got)) call check(err, index(got%message, 'rank 1, expected 2') > 0, got%message)
      call file%read_int('/r', i1, got)
      call check(err, allocated(got), 'type mismatch')
      call file%read_attr('/', 'n', x, got)
      call check(err, allocated(got), 'int attribute read as real')
      call file%read_attr('/', 'n', text, got)
      call check(err, allocated(got), 'int attribute read as string')
      call file%read_attr('/', 'missing', x, got)
      call check(err, allocated(got), 'missing attribute')
      call file%write_real('/s', [1.0_dp], got)
      call check(err, allocated(got), 'writing a read-only file')
      if (allocated(got)) call check(err, got%code == exit_io, 'I/O error code')
      if (allocated(err)) return
      call file%close(err)
   end subroutine test_read_errors

   subroutine test_xdmf(err)
      type(error_t), allocatable, intent(out) :: err
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path, text
      character(len=32), parameter :: node(3) = [character(len=32) :: '/solution/u1', '/solution/u2', &
                                                 '/solution/lambda']
      character(len=32), parameter :: cell(2) = [character(len=32) :: '/estimators/eta_total', '/error/energy']

      path = scratch('case.xdmf', err)
      if (allocated(err)) return
      call write_xdmf(path, 'case.h5', 9_ip, 7_ip, node, cell, err)
      if (allocated(err)) return
      text = read_text(path, err)
      if (allocated(err)) return
      call check(err, index(text, '<Topology TopologyType="Triangle" NumberOfElements="7">') > 0, 'topology')
      call check(err, index(text, 'Dimensions="7 3" Format="HDF">case.h5:/mesh/triangles<') > 0, 'triangles')
      call check(err, index(text, 'Dimensions="9 2" Format="HDF">case.h5:/mesh/vertices<') > 0, 'vertices')
      call check(err, index(text, '<Geometry GeometryType="XY">') > 0, 'geometry')
      call check(err, index(text, '<Attribute Name="lambda" AttributeType="Scalar" Center="Node">') > 0, &
                 'node attribute')
      call check(err, index(text, 'Dimensions="9" Format="HDF">case.h5:/solution/u2<') > 0, 'node dims')
      call check(err, index(text, '<Attribute Name="eta_total" AttributeType="Scalar" Center="Cell">') > 0, &
                 'cell attribute')
      call check(err, index(text, 'Dimensions="7" Format="HDF">case.h5:/error/energy<') > 0, 'cell dims')
      call check(err, count_of(text, '<Attribute ') == 5, 'five attributes')
      call check(err, count_of(text, '</Attribute>') == 5, 'closed')
      call check(err, .not. file_exists(path//'.tmp'//int_text(process_id())), 'temporary file renamed')

      ! into a missing directory: an error naming the path, and nothing left behind
      call write_xdmf(path//'.d/x.xdmf', 'x.h5', 1_ip, 1_ip, node, cell, got)
      call check(err, allocated(got), 'missing directory reported')
      if (allocated(got)) call check(err, got%code == exit_io .and. index(got%message, path//'.d/x.xdmf') == 1, &
                                     'names the path: '//got%message)
      call check(err, .not. file_exists(path//'.d'), 'nothing created')
      call remove_file(path)
   end subroutine test_xdmf

   function read_text(path, err) result(text)
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out) :: err
      character(len=:), allocatable :: text

      integer :: unit, ios, n

      open (newunit=unit, file=path, access='stream', form='unformatted', action='read', status='old', &
            iostat=ios)
      call check(err, ios == 0, 'cannot open '//path)
      if (allocated(err)) then
         text = ''
         return
      end if
      inquire (unit=unit, size=n)
      allocate (character(len=n) :: text)
      read (unit, iostat=ios) text
      close (unit)
      call check(err, ios == 0, 'cannot read '//path)
   end function read_text

   pure integer function count_of(text, pattern) result(n)
      character(len=*), intent(in) :: text, pattern
      integer :: start, k

      n = 0
      start = 1
      do
         k = index(text(start:), pattern)
         if (k == 0) exit
         n = n + 1
         start = start + k
      end do
   end function count_of
end module test_hdf5
