# Site data built at `make` time (nothing here is committed).
# The default site's prior map: the static world as a mapping drive on another day
# saw it (mapping-day parked cars, no traffic), one lap with LiDAR keyframes at 2 Hz,
# assembled by build-map with the ground-truth poses and voxelised at 15 cm.
# Work files carry the shell's PID, so two makes running at once do not read each
# other's half-written logs.
DEFAULT_SITE := maps/default
DEFAULT_MAPPING := $(BUILD)/sites/default-mapping

maps: $(DEFAULT_SITE)/map.pcd $(DEFAULT_SITE)/map.tiles

# The same map prepared and cut into tiles, which the localizer pages in around the car.
$(DEFAULT_SITE)/map.tiles: $(DEFAULT_SITE)/map.pcd $(BIN)/map-tiles
	@echo "  TILES   $@"
	@$(BIN)/map-tiles --map $< --out $@ --quiet

$(DEFAULT_SITE)/map.pcd: $(BIN)/simdrive $(BIN)/build-map $(DEFAULT_SITE)/site.yaml $(DEFAULT_SITE)/route.yaml \
                         $(DEFAULT_SITE)/world.yaml vehicles/prius2017.yaml
	@echo "  SIM     $(DEFAULT_MAPPING) (mapping lap)"
	@tmp=$(DEFAULT_MAPPING).$$$$; rm -rf $$tmp && \
	  $(BIN)/simdrive --mapping --quiet --site $(DEFAULT_SITE) --vehicle vehicles/prius2017.yaml --out $$tmp && \
	  echo "  MAP     $@" && \
	  $(BIN)/build-map --log $$tmp/drive.lcm --pose-channel GROUND_TRUTH \
	    --vehicle vehicles/prius2017.yaml --voxel 0.15 --quiet --out $@.$$$$ && \
	  mv $@.$$$$ $@ && rm -rf $(DEFAULT_MAPPING) && mv $$tmp $(DEFAULT_MAPPING) || { rm -rf $$tmp $@.$$$$; exit 1; }
