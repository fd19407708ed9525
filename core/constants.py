"""Every threshold and random stream of the bake, named in one place (STYLE.md principle 17).

Thresholds are grouped by what they decide; each says where its value comes from
(the paper, a reference, or a measurement). Mechanisms beyond the paper are described in
``docs/DEVIATIONS.md`` and switched by :class:`core.settings.Deviations`.

Random streams: every random draw of a bake comes from
``numpy.random.default_rng([seed, STREAM, ...chunk ids])``, so results depend on the seed
and not on thread count or scheduling. The ids below are part of the golden outputs
(``tools/golden.py``): changing one changes every light map that reads that stream.
"""
from __future__ import annotations

# --------------------------------------------------------------------------- random streams
STREAM_PHOTONS = 1
"""Pass 1: photon emission and bounces, ``[seed, 1, batch]``."""
STREAM_RECORD_ORDER = 2
"""Pass 2: the random order Algorithm 1 walks the photons in, ``[seed, 2]``; after the final neighbour
clamp, the photons it left outside every zone ``[seed, 2, round]`` (deviation: clamp-recovery)."""
STREAM_HOLE_ORDER = 3
"""Section 3.4: the order hole candidates are walked in, ``[seed, 3, round]``."""
STREAM_REFINE = 4
"""Pass 3: refinement of pass 2's records (gathering rays, thinning), ``[seed, 4, batch]``; a later
gather of noisy records ``[seed, 4, batch, round]`` (deviation: adaptive-gathering)."""
STREAM_DIRECT = 10
"""Direct light at texel samples, ``[seed, 10, target stream, chunk]``."""
STREAM_PHOTON_DIRECT = 11
"""Direct light at photons (virtual rays' radiance), ``[seed, 11, chunk]``."""
STREAM_VALIDITY = 12
"""Texel validity rays, ``[seed, 12, target stream, chunk]``."""
STREAM_DIRECT_FOOTPRINT = 13
"""Direct light over edge texels' footprints: jitter ``[seed, 13, target stream]``, shadow rays
``[seed, 13, target stream, 1, chunk]`` (core/direct_footprint.py)."""
STREAM_DIRECT_EDGE = 16
"""The edge probes of soft emitters at texel samples (core/direct.py ``edge_evidence``),
``[seed, 10, target stream, chunk, 16]``."""
STREAM_VALIDITY_FOOTPRINT = 15
"""Texel validity over straddling texels' footprints: jitter ``[seed, 15, target stream]``, rays
``[seed, 15, target stream, 1]`` (core/validity.py ``indirect_weights``)."""
STREAM_REFINE_HOLES = 20
"""Pass 3 on hole records of round r: ``[seed, 20 + r, batch]``."""
STREAM_HIT_GRID = 14
"""Shadow rays at the hit grid's cell centroids (deviation: hit-grid), ``[seed, 14, use, side, chunk]``:
use 0 for pass 3, 1 for the hole records."""
STREAM_SKY = 6
"""Preview's records' own sky rays (deviation: sky-gathering), ``[seed, 6, use, batch]``: use 0 for pass 2's
records, 1 + r for hole records of round r."""
STREAM_CREVICE_REFINE = 31
"""Final gathering at crevice texel points (deviation: crevice-records), ``[seed, 31, batch]``."""
STREAM_DENSITY_CONTROL = 5
"""Section 3.4 density control: which stored photons are discarded, ``[seed, 5]``."""
STREAM_CHR99_SUBSAMPLE = 99
"""The [Chr99] comparator's choice of photons to precompute at, ``[seed, 99]``."""

# --------------------------------------------------------------------------- normal agreement
SAME_SURFACE_COS = 0.7
"""Photons count toward E_k (and coverage probes count as surface) only within ~45 degrees of
n_k: rejects another wall of a corner and the far side of a thin wall (same value as [Chr99]'s
lookups, which share the problem)."""
R_K_SAME_SIDE_COS = 0.5
"""Photons whose normal is within 60 degrees of n_k give R_k's last-hit distances (Figure 3):
last hits of photons on another face of a corner say nothing about this record's view."""
FALLBACK_SAME_SIDE_COS = 0.5
"""The nearest-photon fallback takes a photon within 60 degrees of the hit's normal."""
FALLBACK_EMPTY_DISC = 4.0
"""The nearest-photon fallback lends at most this many photons' power over the disc its photon's
distance spans (deviation: fallback-empty-disc): with no photon on the hit's side nearer than d, an
irradiance E would have put E pi d^2 / power photons there on average, and none lands with
probability exp(-that), under 2 % above 4. 2 bounds more of Sponza's moulding undersides (87 blocks
off instead of 96) but darkens seams it should not (error 8.57 % against 8.45 %)."""

# --------------------------------------------------------------------------- floors
R_K_DISTANCE_FLOOR = 1e-12
"""Last-hit distances below this fraction of R_max count as this (keeps 1/d finite)."""
WALL_MASS_FLOOR = 1e-3
"""The least Epanechnikov mass a wall-cut disc keeps (E_k is divided by it)."""
R_MIN_FLOOR = 1e-9
"""R_min never falls below this fraction of the scene diagonal."""
CELL_DISTANCE_FLOOR = 1e-3
"""No gathering cell is nearer than this fraction of the smallest zone a R_min: a hit at
(nearly) zero distance would make the translational gradient overflow."""
THIN_COVERAGE = 3.0
"""deviation: thin-coverage: a texel sample whose accepted records' Ward weights (Equation 1) sum below
this over a is a hole too, in the first round of hole records: three times Equation 2's threshold, so a
sample read from one record alone must lie within a third of that record's zone (2: within half;
docs/DEVIATIONS.md thin-coverage has both measured)."""
GRADIENT_LIMIT = 0.3
"""Gradient limiting: a record's translational gradient may change E_k by at most this fraction of it
across its zone (|grad_t| <= GRADIENT_LIMIT E_k / (a R_k)). Where the zone is wider than the distances
a hemisphere gradient holds over (a zone at R_min under an overhang), the gradient can point the
wrong way; a texel at the zone's edge then reads E_k moved the wrong way by all the limit allows
(docs/DEVIATIONS.md, gradient-limiting). 0.2 is a tenth of a point better on the real scenes
measured, but holds back the steep, right gradients in a 1 cm gap behind a plate (1.50x a path
tracer there against 1.45x; 1.36x at 0.5)."""
ABOVE_PLANE = 1e-9
"""A virtual ray's previous hit counts as above the record's tangent plane when its height
exceeds this fraction of its distance."""
RADIANCE_FLOOR = 1e-30
"""Mean virtual-ray radiance below this counts as this in the flux-weighted harmonic mean."""
PREVIEW_SKY_ROWS = 16
PREVIEW_SKY_COLUMNS = 32
"""Preview's records cast one ray per cell of this hemisphere to gather the sky (deviation: sky-gathering):
512 rays that are only asked whether they escape; Final's records use their gathering rays."""

# --------------------------------------------------------------------------- record walls (deviation: wall-sectors)
WALL_RAYS = 8
"""Azimuth sectors (one tangent-plane ray each) in which a record's zone ends at the nearest wall."""
WALL_LIFT = 0.05
"""Height of the wall rays above the surface, as a fraction of the zone radius."""
WALL_MARGIN = 1e-3
"""Relative margin that keeps the wall bound off exact ties with grid-aligned texel samples."""
FAR_WALL = 1e6
"""A sector ray that hit nothing stands in as a point this many times its neighbour's distance away."""
SECTOR_OFFSET = 0.3819660112501051
"""Sector grid rotation (radians, 1/phi^2): boundaries and rays never align with axis-aligned grids,
where texel samples would sit exactly on a boundary and float noise would pick the sector."""
TINY_WALL = 1e-30
"""The nearest a wall may be: products of two such lengths stay normal float64."""

# --------------------------------------------------------------------------- surface coverage (deviation: surface-coverage)
COVERAGE_RINGS = 8
COVERAGE_ANGLES = 16
"""Probe points of surface_coverage: COVERAGE_RINGS equal-area rings of COVERAGE_ANGLES each. E_k is
divided by the measured share, so a coarse share biases E_k up where discs cross edges: 4 x 8 probes
left Preview +5.4 % bright on Sponza and +10.8 % on the occluded building; 8 x 16: +1.7 / +7.4 %
(16 x 32: +1.2 / +7.9 %, at no lower error), at no measurable cost."""
COVERAGE_LIFT = 0.05
"""Height above the tangent plane the coverage probes start from, as a fraction of the disc radius."""
COVERAGE_DEPTH = 0.5
"""Depth below the tangent plane, as a fraction of the disc radius, to which the coverage probes look
for surface and photons count: the next of a row of parallel surfaces (a railing's balusters, 30 cm
apart) lies deeper, where a probe, stopped by the first surface, cannot count it but its photons would."""
COVERAGE_FLOOR = 0.05
"""The least kernel share a record is granted: at most 20x amplification of its photons."""

# --------------------------------------------------------------------------- pass 2 density estimation
DENSITY_RECEIVERS = 4
"""Density control: a discarded photon's power is shared among up to this many nearest kept photons
of its surface ([SW00] spreads it over the neighbours; 4 keeps the added noise local)."""
ZONE_PHOTONS = 64
"""Preview: fewest photons a record's zone holds (deviation: zone-photon-floor)."""
R_OVERSAMPLE = 3
"""Neighbours fetched per wanted indirect photon when estimating R_k."""

CLAMP_RECOVERY_ROUNDS = 2
"""Pass 2: rounds of Algorithm 1 over the photons the final neighbour clamp leaves outside every zone
(deviation: clamp-recovery). Sponza at 16 texels/m: 39 % of its photons after the clamp, 1.3 % after
one round (one round: the occluded building held 6.12 % against two rounds' 5.96 %)."""

# --------------------------------------------------------------------------- pass 3 gathering
GATHER_ERROR = 0.05
"""Pass 3: a record gathers again while the standard error of its E_k exceeds this fraction of E_k
(deviation: adaptive-gathering)."""
GATHER_ROUNDS = 4
"""Pass 3: most gathers a record averages (deviation: adaptive-gathering)."""
GATHER_DARK = 0.1
"""Pass 3: records darker than this fraction of the records' mean E_k count their standard error
against that floor: a near-black record's relative noise is not worth extra rays."""
PROBE_RAYS = 16
"""Real rays per record cast before reuse, stratified over the hemisphere (deviation: probe-rays)."""
VIRTUAL_RADIUS = 0.5
"""Photons lend virtual rays only within this fraction of the probe rays' harmonic-mean distance."""
VIRTUAL_PER_CELL = 2.0
"""Virtual rays kept per record, as a multiple of its cells (deviation: virtual-thinning). 8 measured:
Cornell 256^2 Final 8x8-block indirect error 3.98 -> 3.62 % (seed 0), but the white-furnace box's
Final 5.6 -> 7.6 % dark and Sponza's bias -1.8 -> -2.3 %: more cells take photons' pass-2 radiance."""
VIRTUAL_MIN_PER_CELL = 2
"""Cells fewer virtual rays than this reached cast a real ray instead (deviation: virtual-cell-minimum)."""
VISIBILITY_SECTORS = 8
"""Azimuth sectors of a zone whose visibility from the record is tested with one ray each."""
VISIBILITY_LIFT = 0.02
"""Zone-visibility and fallback segments run this fraction of their length above the surface."""
HOLE_NEIGHBOURS = 8
"""Photons searched for one on the hit's side when no pass-2 record covers a gathering ray's hit."""
PORTAL_SHARE = 0.25
"""Share of a sun's or the world's photons sent through the scene's light portals (deviation: portal-photons):
the rest start on the disc around the scene as without portals, lighting its outside. The daylight room
(bench/daylight_room.py --portal, seeds 0-4): 0.25 and 0.5 alike inside (8x8 blocks 1.53 / 1.60 %), 0.5
noisier outside (all texels 2.85 / 3.24 %) and dearer (10.2 / 12.1 CPU s: more photons stay in the room)."""
PHOTON_DIRECT_SAMPLES = 2
"""Shadow-ray samples per photon for its direct irradiance (section 3.1); noise averages over cells."""

# --------------------------------------------------------------------------- transparent shadows (deviation: transparent-shadows)
TRANSPARENT_MAX_LAYERS = 8
"""Transmissive layers a shadow ray or photon path crosses before the next one counts as opaque:
Cycles' default Transparent bounce limit (Light Paths > Max Bounces > Transparent)."""
REFLECTED_SHARE_FLOOR = 1e-6
"""A photon that does not pass a layer reflects with albedo rho / (1 - tau); 1 - tau below this
counts as this (a fully transmissive layer past the layer limit reflects with albedo at most 1)."""

# --------------------------------------------------------------------------- record visibility (deviation: record-visibility)
OFF_PLANE = 4.0
"""A record or photon farther than this many ray epsilons from a point's tangent plane counts only
if it sees the point (RayCaster.hidden_off_plane); nearer, the two are taken as coplanar and cast
no ray. A few epsilons: above the float32 rounding of surface points, far below a 1 cm gap."""
RECORD_STEP_BEHIND = 0.1
"""A record farther than this fraction of its zone radius a R_k *behind* a texel sample's tangent
plane counts only if it sees the sample: a step down (a column base's lower tier, the floor past a
plinth) lies behind the upper surface's plane, within its zones, out of its sight. Nearer, it is
the plane's own curvature (a record a R_k along a sphere of radius 5 a R_k lies 0.1 a R_k behind)."""
NEAREST_RECORDS = 8
"""Records the last-resort fallback tries, nearest first, for one that sees the texel sample
(a box's inside records are the nearest to the floor under it; 8 reach past its bottom's)."""

# --------------------------------------------------------------------------- light-map stage
HOLE_ROUNDS = 3
"""Rounds of hole records (section 3.4) before falling back to the nearest record."""
GAP_TEXELS = 1.0
"""Texel samples no zone accepts first try the records' zones widened by this many texels (deviation:
gap-fill): pass 3 shrinks R_k after pass 2 placed the records, leaving thin gaps between zones.
Wider fills more gaps with fewer hole records, but a sample far past a zone takes E_k from its edge
where the light has moved on; widening zones in proportion to R_k instead carried light into
contact shadows (docs/DEVIATIONS.md gap-fill)."""
FINE_ZONE_TEXELS = 16.0
"""Texels whose smallest accepted zone of influence is narrower than this many texels are
interpolated per sample rather than once at their centroid (deviation: fine-zones): a zone that
narrow changes within a texel. Not every texel: wide zones overlap by the dozen, and per-sample
lookups over all of them cost the Cornell box at 256^2 half its time again (docs/DEVIATIONS.md)."""
VALIDITY_RAYS = 8
"""Hemisphere rays per texel sample (at most) of the texel validity test."""
COVERED_TEXELS = 0.1
"""A texel sample whose first round of validity rays all hit, nearer than this many texels, a face
turned back toward it is inside geometry (core/validity.py: a gap that thin and that wide is dark and
unseen)."""
COVERED_COS = 0.97
"""-cos between such a face's normal and the sample's above which it covers the sample: a sheet
over it. A corner's other face, often lit (Sponza's column flutes by the lamps: -0.85 to -0.91), does not."""
BACKFACE_FRACTION = 0.5
"""A sample is inside geometry when more than this fraction of its rays hit back faces."""
INSIDE_RECORD_RADIUS = 0.05
"""A hole record that record-validity finds inside geometry keeps its E = 0 over a zone of this fraction
of R_min (2 cm at Sponza held's 4 texels/m): its gather speaks for its own point, and at R_k it lent 0 to
lit texels 5 cm away on a capital's flank (0.56x a path tracer; docs/DEVIATIONS.md record-validity)."""
VALIDITY_FOOTPRINT_PER_AXIS = 6
"""Jittered points per axis (36 per texel) that measure how much of a texel straddling a solid's
boundary (a floor texel at a wall's foot) lies inside it (core/validity.py ``indirect_weights``).
With 16 the share's noise was a tenth of the building's squared error at 4 texels/m held; 64 points
gain a little more for twice the votes (docs/DEVIATIONS.md texel-validity)."""
SHARE_TOLERANCE = 1e-6
"""A texel whose footprint's outside share is this close to 1 is whole, not buried (deviation:
buried-texels, core/lightmaps.py): the validity weights' float rounding."""
EVIDENCE_PHOTONS = 8
"""Nearest photons within R_min asked whether light reaches a sample the back-face vote put inside
geometry (deviation: photon-evidence); one that sees the sample's side overrules the vote."""
EVIDENCE_REACH = 0.5
"""Photon-evidence: the photon arrived within this fraction of R_min (one texel at the default
r_min_texels of 2): nearer evidence, as at 4 texels/m R_min is half a metre."""
EVIDENCE_COS = 0.5
"""Photon-evidence: the photon arrived on a surface facing within 60 degrees of the sample's normal
(light on a wall beside a crevice says little about the crevice's floor)."""

# --------------------------------------------------------------------------- direct light over texel footprints
DIRECT_FOOTPRINT_PER_AXIS = 8
"""Stratified jittered points per axis over an edge texel's footprint (64 points): a straight hard
edge's lit share to ~2 % (std), about Cycles' own noise at 256 spp there (core/direct_footprint.py)."""
DIRECT_FOOTPRINT_SIDE = 0.5
"""Default of ``BakeSettings.direct_footprint_side``: width of the footprint, texels, centred on the
texel, that Cycles' bake integrates. Measured on a 30-degree hard edge across a 32^2 plane, Cycles
256 spp against the exact lit share of a centred square (tests/test_direct_footprint.py): Blender
5.0.1 and 5.1.2 side 1.0 rms 10.8 %, 0.75 6.1 %, 0.5 0.46 % (its jitter spans half a texel);
Blender 5.2.3 side 1.0 0.74 %, 0.5 10.7 % (the whole texel). See
:data:`CYCLES_WHOLE_TEXEL_FOOTPRINT`."""
CYCLES_WHOLE_TEXEL_FOOTPRINT = (5, 2, 0)
"""First Blender version measured to bake the whole texel (footprint side 1.0); earlier: 0.5."""
DIRECT_EDGE_CONTRAST = 0.05
"""A texel is an edge texel when its samples' lit shares (core/direct.py edge_evidence) differ by more than this,
or its mean lit share differs by more from a neighbour's on the same surface (lit shares are 1 or
0 away from shadow edges, so smooth falloff never triggers it)."""
DIRECT_EDGE_FLOOR = 1e-3
"""Samples whose unoccluded luminance is below this share of the target's brightest sample count as
fully lit when judging edges (an edge in near-darkness is not worth 64 points)."""
DIRECT_NEIGHBOUR_TEXELS = 2.0
"""Neighbouring texels are compared only if their sample centroids lie within this many texel
sizes of each other (otherwise they are different charts that merely touch in the image)."""

# --------------------------------------------------------------------------- hit grid (deviation: hit-grid)
HIT_GRID_SPACING = 0.5
"""Grid step over triangles / R_min (core/hit_radiance.py). Measured: see docs/DEVIATIONS.md hit-grid."""
HIT_GRID_MAX_SIDE = 256
"""Most grid steps along a triangle's edge (65k cells per side)."""
HIT_GRID_MAX_CELLS = 4_000_000
"""The step widens until the whole grid holds at most this many cells (120 bytes each, core/hit_radiance.py HitGrid)."""
HIT_GRID_CELLS_PER_HIT = 0.125
"""... and at most this many cells (both sides) per gathering hit expected (records x cells)."""
OPEN_CELL_REACH = 0.9
"""How far toward each corner of a grid cell its centroid's three visibility segments reach (deviation:
open-cells, core/hit_radiance.py ``open_cells``): short of the triangle's edges, where neighbours meet it."""
HIT_GRID_NEAR = 1.0
"""A gathering hit nearer to its record than this times its distance from its grid cell's centroid is
shaded on its own (core/real_rays.py): the cell would stand for much of the record's hemisphere."""
GAP_COS = 0.5
"""A gathering hit near its record (the near-hit rule, or within a R_min) whose normal is within 60 degrees
of facing the record's lies in a gap between the two surfaces and gathers its own indirect light; a walk's
vertex that faces the one before it so, within a R_min, is still in the gap (deviation: gap-gathering,
core/real_rays.py)."""
CORNER_REACH = 2.5
"""A gathering hit within this many a R_min of its record and at most CORNER_HEIGHT a R_min above the
record's tangent plane stands at the foot of a surface rising from the record's (a wall above a ledge) and
gathers its own indirect light by the gap walk, facing the record or not (deviation: corner-gathering,
core/real_rays.py). Pass 2's records and photons read on that wall stay flat over a zone where its light
falls toward the corner: on the cathedral's mouldings, a ledge 5-10 cm from the nave wall, the wall's hits
2-30 cm above the ledge and 10-60 cm from the record. Measured: docs/DEVIATIONS.md corner-gathering."""
CORNER_HEIGHT = 1.0
"""... and at most this many a R_min above the record's tangent plane (see CORNER_REACH)."""
GAP_WALK_BOUNCES = 32
"""Most vertices of a gap hit's walk (deviation: gap-gathering, core/real_rays.py:gap_irradiance), which
Russian roulette on the albedo ends sooner (at albedo 0.8, 5 on average); 1 reads records at the walk's
first vertex whatever it meets."""
GAP_WALK_SURVIVAL = 0.05
"""Least survival probability of a gap walk's Russian roulette (a throughput gain of at most 20)."""
SELECTION_LAMPS = 16
"""Point, spot and area lights a scene needs before its gathering hits draw one of them instead of casting a
shadow ray to each (deviation: light-selection, core/light_selection.py). The occluded building with its two lamps
replaced by N spread through it (the same total power), Final, CPU s exact -> drawn: N = 4 25.1 -> 23.8,
8 26.1 -> 25.6 (the draw's own arithmetic about what the rays it saves cost), 16 34.1 -> 29.1, 32 40.8 -> 35.3,
64 59.6 -> 45.5. Below it every lamp keeps its ray (and the light maps their bits)."""
SELECTION_DEFENSIVE = 0.1
"""Share of a gathering hit's lamp draw spread evenly over the lamps with a radius and the area lights
(deviation: light-selection, core/light_selection.py): their centre's weight may call a point dark that they
light."""
BUDGET_LAMPS = 2
"""Soft lamps (area lights, point and spot lights with a radius) a scene needs before a point's soft shadow rays
are shared among them by their unoccluded light instead of ``direct_samples`` each (deviation: light-budget,
core/light_budget.py). Measured: docs/DEVIATIONS.md light-budget."""
BUDGET_SCALE = 4.0
"""A point's shadow rays among soft lamps, as a multiple of ``direct_samples`` (deviation: light-budget): a lamp
gets BUDGET_SCALE x ``direct_samples`` x its share of their light, rounded up to a power of two, at most
``direct_samples``."""
DRAWN_SHARE = 1.0 / 32.0
"""Where a point casts one ray per soft lamp (a footprint's points, core/direct_footprint.py), a lamp giving it this
share of the soft lamps' light or more keeps its ray; the others share one, drawn among them by their shares
(deviation: light-budget)."""
CENTRE_FOOTPRINT_PER_AXIS = 4
"""Strata per axis standing for Cycles' jitter where a texel is sampled on its centre triangle only (deviations
edge-folding and crease-folding, core/raster.py:centre_footprints). Sponza one object at 16 texels/m, the
direct light of its 36k texels at a chart's edge or a crease evaluated over their strata on the centre
triangle, against the competitors bench's 128-spp Cycles pair (noise subtracted): per texel / 8x8 blocks
13.26 / 11.50 % before (quarter-point samples, a barycentric mirror across edges), 2 per axis 7.46 / 8.30 %,
3 7.58 / 7.15 %, 4 6.63 / 4.85 % (the edge texels alone: 4 per axis 7.54 / 5.15 %, 36 jittered points
as Cycles' 7.75 / 6.04 %)."""
CREVICE_RAYS = 5
"""Rays per texel sample whose harmonic mean distance tells a crevice (deviation: crevice-records,
core/crevice_records.py): one along the normal, the rest evenly round a cone of CREVICE_CONE degrees."""
CREVICE_CONE = 60.0
"""Their cone: under a plane h above, the pattern's harmonic mean distance is 5/3 h (a cosine-weighted
one's 1.5 h)."""
CREVICE_DISTANCE = 1.0
"""A texel sample whose rays' harmonic mean distance is below this many a R_min (the narrowest zone) lies in
a crevice and gathers its own record. Measured 0.5-2 (docs/DEVIATIONS.md crevice-records): past 1 the
samples' gathering noise costs the Cornell box its gain and Sponza at 16 texels/m 8 s."""
CREVICE_OFFSETS = 2.0
"""... and not below this many ray offsets (``RayCaster.epsilon``): nearer than that, a crevice record's rays,
which leave the surface an offset off it, misread the gap; such samples keep Equation 3 (the building held
7.33 -> 7.13 %, Sponza held 9.46 -> 9.35 %, the cathedral and the Cornell box within 0.03 point)."""
CREVICE_HEMISPHERE = (8, 16)
"""Cells (theta, phi) of a crevice sample's gathering hemisphere, a quarter of pass 3's, gathered once."""
HIT_GRID_DIRECT_SAMPLES = 4
"""Shadow-ray samples per soft light at each grid cell (hits read the grid, so its noise is shared)."""
