// /docs: Swagger UI over this server's /openapi.json (served from the server itself: no CDN,
// no inline script, so the page's Content-Security-Policy needs no 'unsafe-inline').
window.ui = SwaggerUIBundle({ url: "/openapi.json", dom_id: "#swagger-ui", deepLinking: true });
