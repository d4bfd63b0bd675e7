"""The image pipeline of paper §3, one module per step in the order a frame goes: grey
(``frames``), the median step (``smoothing``), the frame less the empty floor and the
local contrast with a window that follows the objects (``contrast``), binarization
(``threshold``) — the whole way in one function (``segmentation``) —; 8-connected
labeling and moments (``labeling``), perimeter (``perimeter``), compactness and
orientation (``shape``, eq. 13), which blobs are objects (``objects``: not the
background, not specks); a blob's sub-pixel outline (``outline``), markers
(``markers``), boards (``boards``), and reading an image file (``imageio``). Works in
pixels only: knows no camera.
May import: ``config``.
"""
