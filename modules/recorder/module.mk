# recorder: the session recorder (every message on the bus into LCM event logs, 1000-deep queue).
$(eval $(call c_program,recorder,modules/recorder))
