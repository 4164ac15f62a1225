"""Neural implicit surfaces shared by the IGR, DeepSDF, MSC (and MSC-hier), OccNet and ConvONet
plugins.

The method bases and their options (``method_base``, ``occupancy``, ``options``, ``recipes``)
import no torch: the method classes import them at registration time. The rest (networks,
losses, the occupancy LightningModule base, completion) imports torch, and only a method that
trains or completes imports it.
"""
