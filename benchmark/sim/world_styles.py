"""The four city styles: street network, block programme, building and colour parameters.

Distinct on purpose (a model trained on oxford + cambridge is tested on the unseen london):
- ``oxford``: dense old town, curved streets (a strongly warped grid, an organic old core),
  terraces of 2-4 storeys with gabled slate/stone roofs round small blocks, squares,
  honey-coloured limestone facades.
- ``cambridge``: leafy suburb on straight grids (and radial streets round greens), detached houses
  with red-tile gables in gardens, hedges, street trees, striped college lawns and parks.
- ``london``: taller and denser (an irregular, organic medieval core), big blocks of 6-14-storey
  flat-roofed slabs with rooftop plant, brick and Portland-stone/glass facades, a darker grey
  palette, wider roads with bus lanes.
- ``industrial``: grids only (at different angles per district), big flat warehouses with metal
  roofs and skylight strips, concrete yards with trailers and trucks, large parking lots, few
  trees.

Every city is a patchwork of districts, each with its own street-grid angle and pitches (see
``city_districts``), so no street direction dominates a city; the styles differ in the district
kinds they mix (``p_organic``, ``p_radial``, ``old_town``).

Colours are sRGB 0..255 albedos (before sun shading). Lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

RGB = tuple[float, float, float]


@dataclass(frozen=True)
class Style:
    name: str
    block_u: tuple[float, float]  # block pitch across the "u" streets, metres
    block_v: tuple[float, float]
    warp_amp: float  # metres of smooth displacement of the street grid (curved streets)
    warp_cell: float  # wavelength of that displacement, metres
    road_minor: float  # carriageway width, metres
    road_major: float
    major_every: int
    sidewalk: float
    # Block programme: probabilities of the block types (normalised by the generator).
    p_terrace: float
    p_detached: float
    p_slab: float
    p_warehouse: float
    p_park: float
    p_parking: float
    p_lawn: float
    p_plaza: float
    depth: tuple[float, float]  # building depth of terraces / slabs, metres
    parcel: tuple[float, float]  # parcel frontage, metres
    height_low: tuple[float, float]  # terraces / houses eave height above ground, metres
    height_high: tuple[float, float]  # slabs / warehouses
    gable_prob: float
    floor_h: tuple[float, float]
    window_spacing: tuple[float, float]
    roof_colours: tuple[RGB, ...]
    flat_roof_colours: tuple[RGB, ...]
    wall_colours: tuple[RGB, ...]
    window_colours: tuple[RGB, ...]
    grass: RGB
    tree: RGB
    asphalt: RGB
    pavement: RGB
    soil: RGB
    water: RGB
    tree_park: float  # tree candidate acceptance probability in parks / gardens / verges
    tree_garden: float
    tree_street: float
    p_extension: float  # share of terrace parcels with a rear extension
    paved_yard: float  # share of slab courtyards that are paved (the rest are gardens / quads)
    terrain_amp: float  # metres, peak-to-peak about twice this
    river_width: float  # 0 = no river
    church_prob: float = 0.0  # share of plazas holding a church with a spire
    solar_prob: float = 0.0  # share of gabled parcels with solar panels
    railway: bool = False
    bus_lanes: bool = False
    # Districts (city_districts.py): size range, metres; shares of organic (strongly warped, finer)
    # and radial (rings and spokes round a green) districts, the rest are grids; the kind of the
    # district nearest the tile centre ("grid" = no special old core).
    district_m: tuple[float, float] = (500.0, 800.0)
    p_organic: float = 0.0
    p_radial: float = 0.0
    old_town: str = "grid"


STYLE_TABLE: dict[str, Style] = {
    "oxford": Style(
        name="oxford",
        block_u=(55.0, 95.0),
        block_v=(60.0, 110.0),
        warp_amp=70.0,
        warp_cell=520.0,
        road_minor=7.0,
        road_major=11.0,
        major_every=4,
        sidewalk=2.0,
        p_terrace=0.66,
        p_detached=0.0,
        p_slab=0.08,
        p_warehouse=0.0,
        p_park=0.08,
        p_parking=0.05,
        p_lawn=0.06,
        p_plaza=0.03,
        depth=(9.0, 15.0),
        parcel=(6.0, 14.0),
        height_low=(7.0, 13.0),
        height_high=(12.0, 20.0),
        gable_prob=0.8,
        floor_h=(3.0, 3.6),
        window_spacing=(2.6, 3.6),
        roof_colours=((92, 96, 104), (108, 100, 96), (150, 92, 70), (122, 112, 98), (84, 86, 92)),
        flat_roof_colours=((150, 142, 128), (132, 128, 120), (170, 160, 140)),
        wall_colours=((196, 170, 122), (206, 184, 140), (180, 152, 108), (170, 150, 120)),
        window_colours=((52, 60, 72), (64, 70, 78), (40, 46, 56)),
        grass=(92, 128, 62),
        tree=(58, 88, 44),
        asphalt=(92, 92, 94),
        pavement=(168, 160, 146),
        soil=(132, 118, 92),
        water=(62, 84, 88),
        tree_park=0.35,
        tree_garden=0.10,
        tree_street=0.02,
        p_extension=0.6,
        paved_yard=0.15,
        terrain_amp=8.0,
        river_width=34.0,
        church_prob=0.7,
        solar_prob=0.06,
        district_m=(450.0, 750.0),
        p_organic=0.3,
        p_radial=0.08,
        old_town="organic",
    ),
    "cambridge": Style(
        name="cambridge",
        block_u=(100.0, 170.0),
        block_v=(62.0, 92.0),
        warp_amp=12.0,
        warp_cell=800.0,
        road_minor=7.5,
        road_major=12.0,
        major_every=5,
        sidewalk=3.0,
        p_terrace=0.08,
        p_detached=0.62,
        p_slab=0.02,
        p_warehouse=0.0,
        p_park=0.1,
        p_parking=0.04,
        p_lawn=0.05,
        p_plaza=0.01,
        depth=(9.0, 12.0),
        parcel=(16.0, 24.0),
        height_low=(5.0, 7.0),
        height_high=(9.0, 14.0),
        gable_prob=0.95,
        floor_h=(2.8, 3.2),
        window_spacing=(2.8, 4.0),
        roof_colours=((150, 78, 58), (132, 70, 56), (164, 96, 70), (112, 66, 56), (96, 92, 92)),
        flat_roof_colours=((140, 136, 130), (120, 118, 116)),
        wall_colours=((176, 112, 84), (200, 184, 160), (214, 206, 190), (160, 104, 80)),
        window_colours=((46, 54, 64), (58, 64, 70)),
        grass=(88, 140, 60),
        tree=(52, 96, 40),
        asphalt=(100, 100, 102),
        pavement=(176, 172, 164),
        soil=(128, 110, 84),
        water=(58, 90, 96),
        tree_park=0.28,
        tree_garden=0.05,
        tree_street=0.1,
        p_extension=0.4,
        paved_yard=0.2,
        terrain_amp=3.0,
        river_width=24.0,
        church_prob=0.5,
        solar_prob=0.15,
        district_m=(500.0, 800.0),
        p_organic=0.12,
        p_radial=0.1,
        old_town="radial",
    ),
    "london": Style(
        name="london",
        block_u=(80.0, 140.0),
        block_v=(90.0, 160.0),
        warp_amp=35.0,
        warp_cell=900.0,
        road_minor=9.0,
        road_major=16.0,
        major_every=3,
        sidewalk=3.5,
        p_terrace=0.22,
        p_detached=0.0,
        p_slab=0.62,
        p_warehouse=0.0,
        p_park=0.06,
        p_parking=0.02,
        p_lawn=0.0,
        p_plaza=0.03,
        depth=(14.0, 24.0),
        parcel=(14.0, 36.0),
        height_low=(11.0, 17.0),
        height_high=(20.0, 48.0),
        gable_prob=0.35,
        floor_h=(3.4, 4.0),
        window_spacing=(1.8, 3.0),
        roof_colours=((80, 82, 88), (96, 90, 88), (70, 72, 78)),
        flat_roof_colours=(
            (118, 118, 116),
            (96, 98, 100),
            (140, 136, 128),
            (84, 88, 92),
            (150, 140, 120),
            (78, 96, 70),
            (172, 170, 164),
            (62, 64, 68),
        ),
        wall_colours=((150, 92, 72), (216, 208, 188), (122, 128, 138), (110, 80, 66)),
        window_colours=((70, 88, 108), (40, 48, 60), (96, 110, 124)),
        grass=(84, 118, 58),
        tree=(54, 80, 42),
        asphalt=(72, 72, 76),
        pavement=(150, 148, 144),
        soil=(116, 104, 88),
        water=(68, 78, 70),
        tree_park=0.3,
        tree_garden=0.05,
        tree_street=0.12,
        p_extension=0.5,
        paved_yard=0.6,
        terrain_amp=10.0,
        river_width=120.0,
        church_prob=0.2,
        solar_prob=0.04,
        railway=True,
        bus_lanes=True,
        district_m=(550.0, 900.0),
        p_organic=0.25,
        p_radial=0.1,
        old_town="organic",
    ),
    "industrial": Style(
        name="industrial",
        block_u=(160.0, 260.0),
        block_v=(180.0, 300.0),
        warp_amp=6.0,
        warp_cell=1200.0,
        road_minor=10.0,
        road_major=16.0,
        major_every=3,
        sidewalk=1.5,
        p_terrace=0.0,
        p_detached=0.0,
        p_slab=0.06,
        p_warehouse=0.7,
        p_park=0.04,
        p_parking=0.05,
        p_lawn=0.03,
        p_plaza=0.0,
        depth=(18.0, 30.0),
        parcel=(30.0, 60.0),
        height_low=(6.0, 10.0),
        height_high=(9.0, 18.0),
        gable_prob=0.15,
        floor_h=(4.5, 6.0),
        window_spacing=(4.0, 8.0),
        roof_colours=((170, 172, 176), (120, 140, 160), (196, 198, 200)),
        flat_roof_colours=((186, 188, 190), (150, 156, 164), (110, 128, 150), (200, 196, 186)),
        wall_colours=((190, 192, 196), (150, 160, 172), (176, 150, 120), (120, 130, 140)),
        window_colours=((60, 70, 80), (90, 100, 110)),
        grass=(110, 130, 76),
        tree=(64, 90, 50),
        asphalt=(104, 104, 104),
        pavement=(170, 168, 162),
        soil=(150, 136, 110),
        water=(70, 90, 92),
        tree_park=0.2,
        tree_garden=0.03,
        tree_street=0.05,
        p_extension=0.2,
        paved_yard=0.8,
        terrain_amp=4.0,
        river_width=0.0,
        railway=True,
        district_m=(650.0, 1000.0),
    ),
}

STYLES: tuple[str, ...] = ("oxford", "cambridge", "london", "industrial")


def get_style(style: str) -> Style:
    """The parameters of ``style``; ValueError naming the value and the valid styles otherwise."""
    if style not in STYLE_TABLE:
        raise ValueError(f"unknown city style {style!r}; expected one of {STYLES}")
    return STYLE_TABLE[style]
