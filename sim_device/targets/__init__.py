"""Target scattering form functions for the simulated device (TIER-like targets).

Models (time dependence exp(-iωt); far field p_s = f e^{ikr}/r for a unit incident plane
wave, phase referenced to the target centre; TS = 20 log10|f| dB re 1 m²; SI units,
angles in radians):

* :mod:`.spheres`   rigid fixed and elastic solid spheres (modal series, bistatic).
* :mod:`.cylinders` rigid/elastic finite cylinders at any aspect (Faran + Stanton).
* :mod:`.rocks`     flat-rock clutter as a Kirchhoff disc.
* :mod:`.bistatic`  projector–receiver geometry and the monostatic-equivalent rule.
* :mod:`.materials` materials table loader (``config/materials.toml``).

See ``docs/targets.md`` for equations, sources and measured errors.
"""

from ._series import DEFAULT_TOL, target_strength, truncation_start
from .bistatic import (BistaticGeometry, angle_between, bistatic_geometry,
                       equivalent_monostatic_frequency, max_bistatic_angle,
                       sphere_bisector_error)
from .cylinders import (CylinderSeries, cylinder_modal_series, cylinder_rayleigh_form,
                        finite_cylinder_backscatter, finite_cylinder_target_strength,
                        infinite_cylinder_form, infinite_cylinder_form_function,
                        urick_cylinder_broadside_ts)
from .materials import (ElasticMaterial, Fluid, MaterialsError, MaterialTable,
                        get_fluid, get_material, load_materials)
from .rocks import (disc_backscatter, disc_scattering_amplitude, disc_target_strength,
                    kirchhoff_disc_directivity)
from .spheres import (SphereSeries, elastic_sphere_rayleigh_backscatter,
                      rigid_sphere_rayleigh_backscatter, sphere_backscatter,
                      sphere_modal_series, sphere_scattering_amplitude,
                      sphere_target_strength)

__all__ = [
    "DEFAULT_TOL", "target_strength", "truncation_start",
    "BistaticGeometry", "angle_between", "bistatic_geometry",
    "equivalent_monostatic_frequency", "max_bistatic_angle", "sphere_bisector_error",
    "CylinderSeries", "SphereSeries", "cylinder_modal_series", "cylinder_rayleigh_form",
    "finite_cylinder_backscatter",
    "finite_cylinder_target_strength", "infinite_cylinder_form",
    "infinite_cylinder_form_function", "urick_cylinder_broadside_ts",
    "ElasticMaterial", "Fluid", "MaterialsError", "MaterialTable", "get_fluid",
    "get_material", "load_materials",
    "disc_backscatter", "disc_scattering_amplitude", "disc_target_strength",
    "kirchhoff_disc_directivity",
    "elastic_sphere_rayleigh_backscatter", "rigid_sphere_rayleigh_backscatter",
    "sphere_backscatter", "sphere_modal_series", "sphere_scattering_amplitude",
    "sphere_target_strength",
]
