# gnss: u-blox UBX NAV-PVT / NMEA GGA+RMC driver -> GNSS_FIX (docs/gnss.md).
GNSS_CORE := modules/gnss/core
$(eval $(call c_program,gnss,modules/gnss $(GNSS_CORE)))
$(eval $(call c_program,gnss-bench,modules/gnss/bench $(GNSS_CORE)))
$(eval $(call c_test,test_gnss_core,tests/c/test_gnss_core.c $(wildcard $(GNSS_CORE)/*.c)))
$(OBJ)/tests/c/test_gnss_core.o: CPPFLAGS += -I$(TOP)/$(GNSS_CORE)
$(OBJ)/modules/gnss/%.o: CPPFLAGS += -I$(TOP)/$(GNSS_CORE)

BENCH_TARGETS += bench-gnss
.PHONY: bench-gnss
bench-gnss: $(BIN)/gnss-bench
	@$(VPY) modules/gnss/bench/bench_gnss.py --bin $(BIN)/gnss-bench --data tests/data/ublox
