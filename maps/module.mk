# Site data built at `make` time (nothing here is committed), for each bundled site
# (maps/default, maps/hills):
# - map.pcd, the prior map: the static world as a mapping drive on another day saw it
#   (mapping-day parked cars, no traffic), one lap with LiDAR keyframes at 2 Hz,
#   assembled by build-map with the ground-truth poses and voxelised at 15 cm;
# - ground.yaml + ground.pgm, the ground model, derived from map.pcd by build-ground
#   (as it would be for a real site's map).
# Work files carry the shell's PID, so two makes running at once do not read each
# other's half-written logs.
SITES := default hills

define site_rules
maps: maps/$(1)/map.pcd maps/$(1)/ground.yaml maps/$(1)/map.tiles

# The same map prepared and cut into tiles, with the place descriptors of the whole map:
# the localizer pages the tiles in around the car (it refuses tiles of another map.pcd).
maps/$(1)/map.tiles: maps/$(1)/map.pcd $$(BIN)/map-tiles
	@echo "  TILES   $$@"
	@$$(BIN)/map-tiles --map $$< --out $$@ --quiet

maps/$(1)/map.pcd: $$(BIN)/simdrive $$(BIN)/build-map maps/$(1)/site.yaml maps/$(1)/route.yaml \
                   maps/$(1)/world.yaml vehicles/prius2017.yaml
	@echo "  SIM     $$(BUILD)/sites/$(1)-mapping (mapping lap)"
	@tmp=$$(BUILD)/sites/$(1)-mapping.$$$$$$$$; rm -rf $$$$tmp && \
	  $$(BIN)/simdrive --mapping --quiet --site maps/$(1) --vehicle vehicles/prius2017.yaml --out $$$$tmp && \
	  echo "  MAP     $$@" && \
	  $$(BIN)/build-map --log $$$$tmp/drive.lcm --pose-channel GROUND_TRUTH \
	    --vehicle vehicles/prius2017.yaml --voxel 0.15 --quiet --out $$@.$$$$$$$$ && \
	  mv $$@.$$$$$$$$ $$@ && rm -rf $$(BUILD)/sites/$(1)-mapping && mv $$$$tmp $$(BUILD)/sites/$(1)-mapping || \
	  { rm -rf $$$$tmp $$@.$$$$$$$$; exit 1; }

maps/$(1)/ground.yaml: $$(BIN)/build-ground maps/$(1)/map.pcd
	@echo "  GROUND  $$@"
	@$$(BIN)/build-ground --map maps/$(1)/map.pcd --out $$@ --quiet
endef
$(foreach s,$(SITES),$(eval $(call site_rules,$(s))))
