// The parts of three.js that mi_loop's report viewer uses, bundled into one classic script (global THREE).
export {
    AmbientLight, BufferAttribute, BufferGeometry, Color, DirectionalLight, DoubleSide, Float32BufferAttribute,
    HemisphereLight, LineBasicMaterial, LineSegments, Mesh, MeshStandardMaterial, PerspectiveCamera, Points,
    PointsMaterial, REVISION, SRGBColorSpace, Scene, Sphere, Vector3, WebGLRenderer,
} from 'three';
export { OrbitControls } from 'three/addons/controls/OrbitControls.js';
