"""The ``svss`` application: command-line tool and the demo that runs the whole chain.

It sits on top of the three libraries (``svss_daq``, ``svss_proc``, ``sim_device``), which
never import it.
"""
