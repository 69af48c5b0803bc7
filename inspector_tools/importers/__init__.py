"""``inspector import``: third-party datasets (Middlebury, NeRF, IDR, OpenCV) into capture folders.
"""
