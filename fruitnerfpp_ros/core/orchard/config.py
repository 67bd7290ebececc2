"""Settings of counting a whole row (``config/orchard.yaml``, section ``orchard`` of ``fruitnerfpp orchard
--config``): how the row is cut into segments, how their counts are joined, how trees are found, georeferencing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['SegmentConfig', 'MergeConfig', 'TreeConfig', 'GeoConfig', 'OrchardConfig']


def _positive(owner: str, **values: float | None) -> None:
    for name, value in values.items():
        if value is not None and not value > 0:
            raise ConfigError(f'{owner}.{name} must be > 0, got {value!r}')


@dataclass(frozen=True)
class SegmentConfig:
    """How the row is cut: segments of ``length_m`` along the drive (or one per tree of a planting map), each
    trained on the keyframes that see its stretch plus ``margin_m`` on both sides."""

    length_m: float | None = None
    """Length of a segment's own stretch (m); None = one segment per tree when the trees are known (planting map),
    else ``default_length_m``."""
    default_length_m: float = 1.5
    """Segment length without a planting map or ``length_m``."""
    margin_m: float = 0.5
    """A segment's keyframes see its stretch grown by this much on both sides (its fruit there is matched with the
    neighbour's)."""
    trust_fraction: float = 0.2
    """A segment's fruits count up to ``trust_fraction * margin_m`` beyond its stretch (0.1 m: 1.4 apple or 2.4 plum
    diameters). Each fruit in the overlap of two trusted stretches is counted twice and must be paired; the pairs
    that fail (copies a fruit diameter or more apart, a fruit one side split) are the doubles across cuts. On three
    trained 5-tree rows (apple seeds 0 / 1, plum seed 2) 0.6 -> 0.2 gave row F1 0.954 / 0.944 / 0.899 -> 0.964 /
    0.966 / 0.915 (0.964 / 0.971 / 0.921 with the merge's touching-fruit rule) and doubles across cuts 1 / 3 / 3 ->
    0 / 1 / 1; 0.1-0.3 alike, 0 lost true fruit that only the neighbour had counted (docs/results/orchard_rows.md,
    session 30)."""
    min_overlap_m: float = 0.4
    """A keyframe joins a segment when the stretch it sees overlaps the segment's grown stretch by at least this
    much (or the whole grown stretch)."""
    max_views: int = 80
    """At most this many keyframes per segment (evenly thinned): memory and time per segment stay bounded."""
    min_views: int = 6
    """A segment with fewer keyframes is not trained (reported)."""
    standoff_m: float | None = None
    """Distance from the cameras to the row's centre line; None = measured from a drive on both sides (else
    ``default_standoff_m``)."""
    default_standoff_m: float = 2.0
    """Standoff used when only one side was driven and ``standoff_m`` is None."""
    crown_half_depth_m: float = 0.6
    """Half the canopy's depth across the row: a camera sees the stretch where its image edges cross it."""
    max_range_m: float = 8.0
    """Farthest distance a camera is taken to see."""
    box_below_camera_m: float = 1.5
    """A segment's search box reaches this far below the lowest camera (the ground, the lowest fruit), m."""
    box_above_camera_m: float = 2.5
    """... and this far above the highest camera (the crowns' tops), m."""

    def __post_init__(self) -> None:
        _positive('segments', length_m=self.length_m, default_length_m=self.default_length_m,
                  standoff_m=self.standoff_m, default_standoff_m=self.default_standoff_m,
                  crown_half_depth_m=self.crown_half_depth_m, max_range_m=self.max_range_m,
                  box_below_camera_m=self.box_below_camera_m, box_above_camera_m=self.box_above_camera_m)
        if self.margin_m < 0 or not 0 <= self.trust_fraction <= 1 or self.min_overlap_m < 0:
            raise ConfigError('segments: margin_m and min_overlap_m must be >= 0 and trust_fraction in [0, 1]')
        if self.min_views < 1 or self.max_views < self.min_views:
            raise ConfigError('segments: need 1 <= min_views <= max_views')


@dataclass(frozen=True)
class MergeConfig:
    """How the counts of neighbouring segments become one: a fruit both count (in the overlap of their trusted
    stretches) is matched by 3D position and kept once."""

    match_diameters: float = 1.0
    """Two fruits of neighbouring segments are one when their centres are closer than this many fruit diameters
    (the larger of the two, at least ``min_diameter_m``)."""
    min_diameter_m: float = 0.03
    """Smallest diameter used for matching (a fruit seen in a few points gets a tiny diameter)."""
    max_lateral_m: float = 1.5
    """Fruits further than this from the row's centre line are left out (not on this row's trees)."""
    piece_max_diameter_ratio: float = 1.25
    """A segment's unpaired fruit within the match reach of both copies of a pair is a piece of that fruit (the
    segment split it) when the neighbour's copy is one fruit's size: at most this many times the segment's median
    fruit diameter. A larger copy may be two fruits the neighbour merged, and the fruit stays."""
    support_radius_diameters: float = 0.35
    """A fruit one segment counted in a neighbour's trusted stretch, which the neighbour did not count, is dropped
    when the neighbour's fruit cloud has no point within this many fruit diameters (the segment's median) of it:
    the neighbour's views saw the place and found no fruit surface there. 0 = keep every such fruit."""

    def __post_init__(self) -> None:
        _positive('merge', match_diameters=self.match_diameters, min_diameter_m=self.min_diameter_m,
                  max_lateral_m=self.max_lateral_m, piece_max_diameter_ratio=self.piece_max_diameter_ratio)
        if not self.support_radius_diameters >= 0:
            raise ConfigError(f'merge.support_radius_diameters must be >= 0, got {self.support_radius_diameters!r}')


@dataclass(frozen=True)
class TreeConfig:
    """How trees are found when no planting map is given: each tree's crown is a shell its fruits hang on, one
    sphere per tree fitted to the fruits (trees = the number of spheres with the best BIC), trunks below them."""

    spacing_m: float | None = None
    """Known tree spacing along the row (m); None = the number of trees is chosen from the data."""
    min_spacing_m: float = 0.3
    """Trees are at least this far apart (bounds the number of trees tried)."""
    min_fruits_per_tree: int = 3
    """A fitted tree with fewer fruits is merged into its neighbours."""
    iterations: int = 25
    """Fit iterations per number of trees tried."""
    complete_margin_m: float = 0.2
    """Live counts: a tree is complete when its crown (trunk +- half a spacing) plus this lies in finished
    segments."""
    assign: str = 'crown'
    """Which tree a fruit goes to: ``crown``, the tree whose crown shell (a sphere fitted to the fruit, started from
    the trunks) it lies closest to, so a large crown keeps the fruit it reaches past the midpoint to a small
    neighbour; ``trunk``, the nearest trunk (horizontal distance)."""
    crown_min_fruits: int = 12
    """``crown``: a tree with fewer fruits gets no fitted crown (a sphere through a few points is no crown); its
    fruit go by the median crown radius round its trunk's vertical, and with no fitted crown at all by trunk."""

    def __post_init__(self) -> None:
        _positive('trees', spacing_m=self.spacing_m, min_spacing_m=self.min_spacing_m)
        if self.min_fruits_per_tree < 1 or self.iterations < 1 or self.complete_margin_m < 0:
            raise ConfigError('trees: min_fruits_per_tree and iterations must be >= 1, complete_margin_m >= 0')
        if self.assign not in ('crown', 'trunk') or self.crown_min_fruits < 4:
            raise ConfigError(f'trees: assign must be crown or trunk (got {self.assign!r}), crown_min_fruits >= 4')


@dataclass(frozen=True)
class GeoConfig:
    """World frame <-> WGS84."""

    datum: tuple[float, ...] | None = None
    """Latitude, longitude (deg), ellipsoidal height (m) of the world origin and optionally the heading of the
    world x axis (deg counter-clockwise from east); None = estimated from GNSS fixes."""
    antenna_in_camera_m: tuple[float, float, float] | None = None
    """GNSS antenna in the camera optical frame (x right, y down, z forward), m; None = gnss.json's value or the
    camera itself."""
    outlier_sigma: float = 3.0
    """Fixes further from the fit than this many robust standard deviations are dropped."""
    max_gap_s: float = 1.0
    """A fix between keyframes further apart in time than this is not used."""
    row_id: str = '1'
    """The row's name in trees.csv / GeoJSON / the report."""

    def __post_init__(self) -> None:
        if self.datum is not None and len(self.datum) not in (3, 4):
            raise ConfigError('geo.datum must be [latitude, longitude, altitude] or [..., yaw_deg]')
        _positive('geo', outlier_sigma=self.outlier_sigma, max_gap_s=self.max_gap_s)


@dataclass(frozen=True)
class OrchardConfig:
    """Everything of a row count besides the per-segment train / export / clustering configs."""

    segments: SegmentConfig = field(default_factory=SegmentConfig)
    merge: MergeConfig = field(default_factory=MergeConfig)
    trees: TreeConfig = field(default_factory=TreeConfig)
    geo: GeoConfig = field(default_factory=GeoConfig)
