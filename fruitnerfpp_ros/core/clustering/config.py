"""Configuration of the fruit counting stage (multi-modal clustering of the exported fruit point cloud)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['ClusterConfig', 'MaskFruitConfig']


@dataclass(frozen=True)
class MaskFruitConfig:
    """The count checked against the training views' instance masks (``mask_check.py``): fruit triangulated from
    the masks the cloud's count leaves unexplained (``mask_fruits.py``), pieces of one fruit joined
    (``mask_pieces.py``).

    Defaults set on the ``cpu`` and ``quick`` suites' trained fields, judged on the ``holdout`` suite
    (docs/results/accuracy_suite.md, session 31)."""

    enabled: bool = True
    """Check the count against the masks (off: the count is the cloud's clusters alone)."""
    min_mask_pixels: int = 6
    """Smaller masks are left out (a few pixels' centroid gives no ray to trust: where the fruit span tens of pixels,
    a mask this small is a sliver of a hidden fruit, its centroid off the fruit's centre) ..."""
    min_mask_share: float = 0.15
    """... unless the scene's fruit are small in the views: the floor is then this share of a whole fruit's mask
    (the 90th percentile of the masks' areas over the views; whole fruits are the largest masks) ..."""
    smallest_mask_pixels: int = 3
    """... but never below this many pixels. Plums in a row drive cover 10-15 px when whole (4-6 px across): 28 of the
    38 plums missed with a 6 px floor never have a 6 px mask (docs/results/accuracy_suite.md, session 34)."""
    explained_share: float = 0.5
    """A mask is explained when this share of its pixels lies on the discs of the counted fruits."""
    disc_radius_factor: float = 1.2
    """A counted fruit's disc in a view: this many times its projected radius (the centres are not exact) ..."""
    disc_margin_px: float = 1.0
    """... plus this many pixels (masks and projections are whole pixels: a fruit a few pixels wide is all edge)."""
    ray_gap_diameters: float = 0.5
    """Two masks' rays meet when they pass within this many fruit diameters of each other."""
    max_depth_factor: float = 1.4
    """A mask's fruit lies no farther than this times the depth at which a whole fruit spans the mask."""
    min_views: int = 3
    """A fruit needs unexplained masks of at least this many views whose rays meet at it."""
    chance_draws: int = 4
    """``min_views`` is raised until fruit that views agree on by chance are rare: the unexplained masks' rays are
    shuffled this many times (``mask_fruits.shuffled_rays``) and triangulated like the real ones; the floor is the
    lowest at which the shuffles give at most ``max_chance_share`` times as many fruit as the real rays. A
    segmenter's false detections agree by chance as well as leaves do (0: ``min_views`` as it is)."""
    chance_shift_diameters: float = 3.0
    """A shuffle turns each view's rays together by the angle this many fruit diameters span at their depth."""
    max_chance_share: float = 0.2
    """See ``chance_draws``."""
    chance_seed: int = 0
    """Seed of the shuffles (the count is the same on every run)."""
    min_separation_diameters: float = 1.0
    """No fruit is added this close (in fruit diameters) to a counted or an added one."""
    min_camera_distance_m: float = 0.1
    """A fruit lies at least this far in front of each camera that sees it."""
    join_pieces: bool = True
    """Join two counted fruits the masks show as pieces of one fruit (``mask_pieces.py``)."""
    join_within_diameters: float = 2.0
    """... when their centres lie within this many fruit diameters ..."""
    join_min_shared_views: int = 3
    """... and project onto the same instance mask in at least this many training views ..."""
    join_max_split_views: int = 0
    """... and onto two different masks in at most this many."""
    split_merges: bool = True
    """Cut in two a counted fruit the masks show as two touching fruits (``mask_merges.py``; on the fields of 40
    suite scenes and 14 rows: F1 up on 15 scenes and 7 rows, down on no scene and 1 row, docs/results/orchard_rows.md,
    session 38) ..."""
    split_min_views: int = 3
    """... when its disc holds two or more masks in at least this many training views ..."""
    split_view_share: float = 0.5
    """... and in at least this share of the views in which it holds any ..."""
    split_min_separation_diameters: float = 0.6
    """... and the two halves' centres lie at least this many fruit diameters apart."""
    skip_mask_sources: tuple[str, ...] = ('fallback',)
    """Masks of these sources (the dataset's ``mask_source``; a joined one when any of its parts is listed) are not
    used, nothing is added or joined: the built-in colour segmenter merges fruit and marks leaves, and its
    unexplained masks agree where no fruit hangs (4 ``cpu`` scenes with its masks: mean F1 0.774 without the step,
    0.726 with it)."""

    def __post_init__(self) -> None:
        checks = [(1 <= self.smallest_mask_pixels <= self.min_mask_pixels,
                   'smallest_mask_pixels must be >= 1 and <= min_mask_pixels'),
                  (self.min_mask_share >= 0, 'min_mask_share must be >= 0'),
                  (0 < self.explained_share <= 1, 'explained_share must be in (0, 1]'),
                  (self.disc_radius_factor > 0 and self.disc_margin_px >= 0,
                   'disc_radius_factor must be > 0 and disc_margin_px >= 0'),
                  (self.ray_gap_diameters > 0, 'ray_gap_diameters must be > 0'),
                  (self.max_depth_factor > 0, 'max_depth_factor must be > 0'),
                  (self.min_views >= 2, 'min_views must be >= 2 (one view cannot place a fruit in depth)'),
                  (self.chance_draws >= 0 and self.chance_shift_diameters > 0 and self.max_chance_share >= 0,
                   'chance_draws and max_chance_share must be >= 0, chance_shift_diameters > 0'),
                  (self.min_separation_diameters >= 0, 'min_separation_diameters must be >= 0'),
                  (self.min_camera_distance_m >= 0, 'min_camera_distance_m must be >= 0'),
                  (self.join_within_diameters > 0, 'join_within_diameters must be > 0'),
                  (self.split_min_views >= 1 and 0 <= self.split_view_share <= 1
                   and self.split_min_separation_diameters >= 0,
                   'split_min_views must be >= 1, split_view_share in [0, 1], split_min_separation_diameters >= 0'),
                  (self.join_min_shared_views >= 1 and self.join_max_split_views >= 0,
                   'join_min_shared_views must be >= 1 and join_max_split_views >= 0')]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f'MaskFruitConfig: {message}')


@dataclass(frozen=True)
class ClusterConfig:
    """How the fruit point cloud is split into fruits.

    The distance between points k and l is the paper's sum
    ``d = lambda_c * (1 - cos(i_k, i_l)) + lambda_e * |x_k - x_l|`` (metres), evaluated exactly on the pairs of a
    sparse neighbour graph whose candidates come from a KD-tree on xyz (``d >= lambda_e * |dx|``).
    """

    lambda_c: float = 1.0
    """Weight of the embedding (cosine) term, dimensionless; the paper's lambda_c = 1."""

    lambda_e: float = 2.0
    """Weight of the Euclidean term in 1/m. Tuned on the synthetic clouds (7 cm apples, 60-600 points per
    fruit, touching triples): ARI 1.0 for 0.5-3/m; at 5/m the sparsest clouds start to merge touching fruits and
    at 10/m a 1.6 cm neighbour step (0.16) swamps the cosine gap at a contact (0.3-0.4). Far-apart fruits never
    share an edge of the spatial kNN graph, so a small lambda_e does not merge them. The paper's 1 and 5 were in
    its own normalised scene units, not metres."""

    metric: Literal['summed', 'concatenated'] = 'summed'
    """``summed``: the paper's metric, exact on the graph's pairs. ``concatenated``: the common approximation
    ``sqrt(lambda_e^2 |dx|^2 + lambda_c (1 - cos))`` (Euclidean distance of concatenated scaled features); its
    thresholds do not transfer from ``summed``."""

    knn_k: int = 24
    """Neighbours per point kept in the sparse graph (smallest metric values among the candidates)."""

    candidate_factor: float = 2.0
    """KD-tree candidates per point = ``candidate_factor * knn_k``; a row is exact when its k-th smallest metric
    value is within ``lambda_e`` times the candidate radius (fraction reported in the stats)."""

    min_cluster_size: int = 15
    """HDBSCAN minimum cluster size, in points of the clustered set (scaled down with the subsample fraction,
    never below ``min_samples``). Given for ``reference_spacing_m``."""

    min_samples: int = 8
    """HDBSCAN min_samples (core distance neighbour), must be <= ``knn_k``. Not scaled with the spacing: scaled up
    it smoothed away the boundaries between touching fruit on subsampled clouds."""

    min_fruit_points: int = 20
    """Clusters with fewer points in the full cloud are dropped as noise (label 0) before counting. Given for
    ``reference_spacing_m``."""

    reference_spacing_m: float | None = 0.02
    """Point spacing (m) for which ``min_cluster_size`` and ``min_fruit_points`` are given. A fruit's surface holds
    ~1/spacing^2 points, so a cloud of spacing s (``FruitPointCloud.spacing_m``: the export voxel, kept in the PLY
    and npz files) is clustered with those sizes times (reference / s)^2: without it a finer export splits fruits
    into small fragments that pass the size limits (tiny scene at 1.2 cm voxels: F1 0.64 -> 0.83). None: the sizes
    are used as given (also when the cloud's spacing is unknown)."""

    fruit_share_cluster: float | None = 0.2
    """With a cloud that knows its fruit diameter D: ``min_cluster_size`` = this x the points a fruit shows (the
    median number of cloud points within D / 2 of a point, measured on the cloud), which follows the image
    resolution, the views and the export voxel without a reference. None: the spacing-scaled value."""

    fruit_share_keep: float | None = 0.5
    """... and ``min_fruit_points`` = this x the points a fruit shows (a fruit's cluster holds about twice that
    number; smaller ones are pieces at a fruit's edge or a field's ghosts). 0.5 over 0.4 (session 38 in
    docs/results/accuracy_suite.md): mean F1 up on the ``cpu`` + ``holdout`` + ``quick`` fields (23 scenes), their
    ``tiny`` fields (17) and 14 rows, level with the fallback masks; 0.6 loses plums. None: the spacing-scaled
    value."""

    reference_fruit_diameter_m: float | None = 0.075
    """Fruit diameter (m) for which ``lambda_e``, ``overlap_m``, ``merge_*_m`` and (with
    ``reference_spacing_m``) the cluster sizes are given: a cloud that knows its scene's fruit diameter
    (``FruitPointCloud.fruit_diameter_m``) is clustered with them scaled to it (:meth:`for_cloud`). None: as given."""

    centre_shift_diameters: float = 0.3333
    """Before clustering, each point of a cloud that knows its points' viewing directions
    (``FruitPointCloud.view_dir``) moves this many fruit diameters along its mean viewing direction, towards the
    centre of the fruit whose surface it is, and fruit centres are the medians of the moved points (diameters and
    extents stay those of the surface points). A ray that meets a sphere of radius r anywhere on its disc ends on
    average 2/3 r in front of the centre along the ray, so 1/3 diameter puts a cap's points around its fruit's
    centre, and the two caps of a fruit seen from the two sides of a row (0.6-1.4 diameters apart on the surface)
    onto one place. Uses the cloud's fruit diameter (else ``reference_fruit_diameter_m``). 0 disables."""

    merge_opposite_m: float = 0.045
    """Clusters seen from opposite sides (mean viewing directions' cosine at most ``opposite_facing_cos``) whose
    centres, after ``centre_shift_diameters``, lie closer than this (m; 0.6 reference diameters) are one fruit: a
    fruit's two caps from the two sides of a row whose embeddings disagree (core/clustering/merge.py). On 30 trained
    clouds (suites and the 5-tree row): 12 of 24 such pairs halving one fruit lie within 0.6 diameters, none of 47
    pairs of two fruits within 0.7. Needs the cloud's viewing directions and a shift > 0; 0 disables."""

    opposite_facing_cos: float = -0.5
    """Largest cosine between two clusters' mean viewing directions for ``merge_opposite_m``."""

    merge_centers_m: float = 0.0
    """Clusters whose median centres are closer than this (m) are merged into one fruit (a fruit split in two by
    a noisy embedding has half-centres about 0.4 diameters apart; two real fruits cannot be closer than ~0.8
    diameters). 0 disables."""

    merge_agreeing_m: float = 0.1125
    """Clusters whose median centres are closer than this (m; 1.5 reference diameters) and whose mean embeddings
    agree (cosine >= ``merge_agreeing_cos``) are merged into one fruit, after the split of oversized clusters: a
    fruit seen from both sides of a row is exported as two caps (front and back, 0.6-1.4 diameters apart) that the
    instance field gives one embedding, while touching fruits' embeddings differ (core/clustering/merge.py;
    docs/results/accuracy_suite.md: the 5-tree row F1 0.914 -> 0.969, the suite's fields +0.007 mean F1 with GT
    masks, -0.008 with the fallback masks). 0 disables."""

    merge_agreeing_cos: float = 0.8
    """Smallest cosine between two clusters' mean unit embeddings for ``merge_agreeing_m``. On the fields of today's
    training the cap pairs left split agree less (5-tree row: median 0.58, 90th percentile 0.85) while pairs of two
    fruits stay apart (median 0.12, 3 of 166 at >= 0.8): 0.9 -> 0.8 re-counted the `cpu` suite's 13 fields 0.880 ->
    0.883 with GT masks and the fallback masks' 7 fields 0.650 -> 0.653, no scene lower; the 5-tree row 0.891 ->
    0.899 (docs/results/accuracy_suite.md, "The caps' join at 0.8"). 0.7 lost on the fallback masks."""

    cluster_selection_method: Literal['eom', 'leaf'] = 'eom'
    """HDBSCAN cluster selection: excess of mass (default) or leaves. 'leaf' separated touching fruit better on
    every exported tiny-scene cloud measured (F1 0.97 / 0.93 / 0.68 against 0.92 / 0.84 / 0.21 on three seeds,
    docs/results/tiny_preset.md) but splits large clusters: solid spheres exported at 6 mm become 6 clusters
    instead of 4, and unscaled sizes on dense clouds shatter every fruit (ARI 0.001)."""

    partitions: int = 0
    """Number S of k-means spatial partitions; 0 chooses ``ceil(n / points_per_partition)``."""

    points_per_partition: int = 25000
    """Target partition size when ``partitions`` is 0."""

    overlap_m: float = 0.12
    """Each partition also clusters the points within this distance (m) of its Voronoi cell, and keeps the
    clusters whose median lies in its own cell; must exceed the largest fruit diameter so a fruit cut by a
    boundary is seen whole (and counted once). 0 disables overlap (a cut fruit is then counted twice)."""

    subsample_size: int = 60000
    """Clouds larger than this are clustered on a random subsample of this size and every other point takes the
    label of its nearest subsample point under the same metric (Contrastive Lift's shortcut). 0 disables."""

    assign_k: int = 8
    """KD-tree candidates per point when assigning the non-subsampled points."""

    n_jobs: int = 2
    """Worker processes for the partitions (1 = in this process) and threads for KD-tree queries."""

    parallel_min_points: int = 40000
    """Below this many clustered points all partitions run in this process (a process pool costs more)."""

    cluster_selection_epsilon: float = 0.0
    """HDBSCAN cluster_selection_epsilon, in units of the metric d: clusters that split below this distance stay
    one cluster. 0 disables (the default): 0.3 and 0.5 merged neighbouring fruits on the exported tiny-scene
    clouds (F1 0.92 -> 0.75 / 0.40), whose fruits are bridged by points of intermediate embedding."""
    split_diameter_factor: float = 1.5
    """Clusters wider than this many times the median cluster diameter are clustered again on their own with
    'leaf' selection (core/clustering/split.py): 'eom' keeps touching fruits together. On the exported
    tiny-scene clouds of docs/results/tiny_preset.md: F1 0.92 / 0.88 / 0.95 -> 0.92 / 0.91 / 0.98. 0 disables."""
    seed: int = 0
    """Random seed for the subsample and k-means."""
    masks: MaskFruitConfig = field(default_factory=MaskFruitConfig)
    """After the clustering: fruit the training views' unexplained masks agree on (core/clustering/mask_fruits.py;
    applied where the views are at hand: the pipeline, ``fruitnerfpp count RUN_DIR``)."""

    def __post_init__(self) -> None:
        checks = [
            (self.lambda_c >= 0, 'lambda_c must be >= 0'),
            (self.lambda_e > 0, 'lambda_e must be > 0 (the KD-tree candidate search relies on it)'),
            (self.knn_k >= 2, 'knn_k must be >= 2'),
            (self.candidate_factor >= 1.0, 'candidate_factor must be >= 1'),
            (1 <= self.min_samples <= self.knn_k, 'min_samples must be in [1, knn_k]'),
            (self.min_cluster_size >= 2, 'min_cluster_size must be >= 2'),
            (self.min_fruit_points >= 1, 'min_fruit_points must be >= 1'),
            (self.reference_spacing_m is None or self.reference_spacing_m > 0, 'reference_spacing_m must be > 0'),
            (self.reference_fruit_diameter_m is None or self.reference_fruit_diameter_m > 0,
             'reference_fruit_diameter_m must be > 0'),
            (all(v is None or 0 < v <= 1 for v in (self.fruit_share_cluster, self.fruit_share_keep)),
             'fruit_share_cluster and fruit_share_keep must be in (0, 1] or null'),
            (self.partitions >= 0, 'partitions must be >= 0'),
            (self.points_per_partition >= 100, 'points_per_partition must be >= 100'),
            (self.overlap_m >= 0, 'overlap_m must be >= 0'),
            (self.merge_centers_m >= 0, 'merge_centers_m must be >= 0'),
            (0 <= self.centre_shift_diameters <= 1, 'centre_shift_diameters must be in [0, 1]'),
            (self.merge_opposite_m >= 0, 'merge_opposite_m must be >= 0'),
            (-1 <= self.opposite_facing_cos <= 0, 'opposite_facing_cos must be in [-1, 0]'),
            (self.merge_agreeing_m >= 0, 'merge_agreeing_m must be >= 0'),
            (-1 <= self.merge_agreeing_cos <= 1, 'merge_agreeing_cos must be in [-1, 1]'),
            (self.cluster_selection_epsilon >= 0, 'cluster_selection_epsilon must be >= 0'),
            (self.split_diameter_factor == 0 or self.split_diameter_factor >= 1,
             'split_diameter_factor must be 0 or >= 1'),
            (self.subsample_size == 0 or self.subsample_size >= 1000, 'subsample_size must be 0 or >= 1000'),
            (self.assign_k >= 1, 'assign_k must be >= 1'),
            (self.n_jobs >= 1, 'n_jobs must be >= 1'),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f'ClusterConfig: {message}')

    def for_cloud(self, spacing_m: float | None, fruit_diameter_m: float | None = None,
                  fruit_points: float | None = None) -> 'ClusterConfig':
        """This config scaled to a cloud of point spacing ``spacing_m`` and fruit diameter ``fruit_diameter_m``.

        Lengths (``lambda_e`` inversely, ``overlap_m``, ``merge_centers_m``, ``merge_agreeing_m``,
        ``merge_opposite_m``) scale with the
        fruit diameter over ``reference_fruit_diameter_m``. Cluster sizes: the ``fruit_share_*`` of ``fruit_points``
        (the points a fruit shows, measured on the cloud) when given, else the points a fruit holds, (fruit diameter
        / spacing)^2, over the reference's. Unknown values (None) leave their part unscaled.
        """
        out = self
        ratio = 1.0
        if fruit_diameter_m is not None and fruit_diameter_m > 0 and self.reference_fruit_diameter_m is not None:
            ratio = fruit_diameter_m / self.reference_fruit_diameter_m
            out = dataclasses.replace(out, lambda_e=self.lambda_e / ratio, overlap_m=self.overlap_m * ratio,
                                      merge_centers_m=self.merge_centers_m * ratio,
                                      merge_opposite_m=self.merge_opposite_m * ratio,
                                      merge_agreeing_m=self.merge_agreeing_m * ratio)
        if fruit_points is not None and fruit_points > 0:
            if self.fruit_share_cluster is not None:
                out = dataclasses.replace(out, min_cluster_size=max(2, round(self.fruit_share_cluster * fruit_points)))
            if self.fruit_share_keep is not None:
                out = dataclasses.replace(out, min_fruit_points=max(1, round(self.fruit_share_keep * fruit_points)))
            if self.fruit_share_cluster is not None and self.fruit_share_keep is not None:
                return out
        if spacing_m is None or self.reference_spacing_m is None or not spacing_m > 0:
            return out
        scale = (ratio * self.reference_spacing_m / spacing_m) ** 2
        if fruit_points is None or self.fruit_share_cluster is None:
            out = dataclasses.replace(out, min_cluster_size=max(2, round(self.min_cluster_size * scale)))
        if fruit_points is None or self.fruit_share_keep is None:
            out = dataclasses.replace(out, min_fruit_points=max(1, round(self.min_fruit_points * scale)))
        return out
