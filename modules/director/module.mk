# director: scenario runtime (core/ is pure: scenario loader, geometry, runtime; main.c the shell).
$(eval $(call c_program,director,modules/director modules/director/core,-lccd))
