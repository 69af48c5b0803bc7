"""``inspector bench``: the pipeline, the 5 MP path, the GUI, the Aravis driver and the OPC UA server, timed.
"""
