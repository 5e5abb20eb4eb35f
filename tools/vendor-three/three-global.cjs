// 'three' inside the GLTFLoader bundle: the THREE that three.min.js defined on the page.
module.exports = globalThis.THREE;
