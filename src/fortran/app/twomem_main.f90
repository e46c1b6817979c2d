program twomem_main
   use twomem_base_version, only: twomem_version
   implicit none
   write (*, '(a)') 'twomem '//twomem_version
end program twomem_main
