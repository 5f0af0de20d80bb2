# supervisor: keeps a stack of commands running (core/ is pure: stack files, the per-command
# state machine; main.c the shell); supervisorctl operates it over LCM.
$(eval $(call c_program,supervisor,modules/supervisor modules/supervisor/core))
$(eval $(call c_program,supervisorctl,modules/supervisor/ctl))
$(eval $(call c_test,test_supervisor,tests/c/test_supervisor.c $(call dir_c,modules/supervisor/core)))
