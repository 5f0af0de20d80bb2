# import-candump: candump -l text log -> CAN_FRAME events in an LCM log.
$(eval $(call c_program,import-candump,tools/import-candump))
