"""The image pipeline of paper §3: grey, median, binarize (``preprocess``), the object
pixels with a local-contrast window that follows the objects (``segmentation``), 8-connected
labeling and moments (``labeling``), perimeter (``perimeter``), compactness and
orientation (``shape``, eq. 13), which blobs are objects (``objects``: not the
background, not specks), and reading an image file (``imageio``). Works in pixels only:
knows no camera.
May import: ``config``.
"""
