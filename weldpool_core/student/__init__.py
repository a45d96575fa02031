"""The student: a ResNet-VAE that learns the pool's mask and keypoint heatmap from labels.

``model`` (the network and its sizes), ``data`` (geometry, targets, augmentation, DATASET
folders), ``train`` (``train_student``), ``checkpoint`` (the MODEL_DIR), ``predict``
(``StudentPredictor``) and ``export`` (ONNX, TorchScript).
"""
