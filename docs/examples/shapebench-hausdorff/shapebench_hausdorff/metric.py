import numpy as np
from scipy.spatial import cKDTree

from shapebench import UNIT_SPHERE_FRAME, Completion, Context, Metric, MetricCard, ObjectData


class Hausdorff(Metric):
    name = "hausdorff"  # the public name: --metric hausdorff
    description = "largest distance from a point of either set to the other set"
    higher_is_better = False  # the card says the same

    def card(self, eval_points: int) -> MetricCard:
        return MetricCard(
            metric=self.name,
            power=1,  # Euclidean, not squared
            reduction="max",  # the farthest point of each set...
            direction="symmetric",
            combine="max",  # ...and the larger of the two directions
            halved=False,
            scale=100.0,  # leaderboards show values x100
            frame=UNIT_SPHERE_FRAME,  # the runner sets the run's frame
            eval_points=eval_points,
        )

    def compute(self, prediction: Completion, ground_truth: ObjectData, context: Context) -> float:
        pred = np.asarray(prediction.points, dtype=np.float64)
        # the ground truth's tree is shared by every completion of this object
        tree = ground_truth.cache.get("hausdorff.gt_tree")
        if tree is None:
            tree = ground_truth.cache["hausdorff.gt_tree"] = cKDTree(ground_truth.gt_points)
        pred_to_gt = tree.query(pred)[0].max()
        gt_to_pred = cKDTree(pred).query(ground_truth.gt_points)[0].max()
        return float(max(pred_to_gt, gt_to_pred))
