"""From shards to batches on the training device: samples (``dataset``), the opt-in decoded copy
(``decoded_cache``, its entries checked by ``decoded_manifest``), sampling and batching
(``loader``, with ``batch_transfer``'s shared-memory ring), compact-to-float batches
(``batch_format``) and the copy to the GPU (``device_prefetch``).
Imports ``settings`` and ``paper`` (``batch_format`` downsamples masks as the losses do)."""
