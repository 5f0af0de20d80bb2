# ouster: Ouster lidar/IMU UDP driver (docs/ouster.md). core/ is the pure core (packets,
# metadata, frames, pcap), main.c the shell.
$(eval $(call c_program,ouster,modules/ouster modules/ouster/core,-lcjson))
# ouster-points: LIDAR_SCAN points through common/pb_scan as CSV (checks xyz against references).
$(eval $(call c_program,ouster-points,modules/ouster/points))
# ouster-bench: per-frame CPU cost on a real capture (make bench-ouster prints the table).
$(eval $(call c_program,ouster-bench,modules/ouster/bench modules/ouster/core,-lcjson))
BENCH_TARGETS += bench-ouster
.PHONY: bench-ouster
bench-ouster: $(BIN)/ouster-bench
	@bash modules/ouster/bench/bench.sh
